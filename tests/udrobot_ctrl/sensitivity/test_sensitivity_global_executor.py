"""Sobol/Morris through the executor (processes and a dask LocalCluster), and crash-safe resume."""
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from udrobot_ctrl.sensitivity.executor import SweepExecutor, run_sweep
from udrobot_ctrl.sensitivity.global_ import Ishigami, run_morris, run_sobol
from udrobot_ctrl.sensitivity.results import ResultStore, read_csv_table


@pytest.mark.slow
def test_sobol_recovers_ishigami_indices_within_ci_on_local_processes(tmp_path):
    f = Ishigami()
    with SweepExecutor(workers=2) as ex:
        res = run_sobol(f, f.problem(), 2048, executor=ex, out=tmp_path / "ishigami", seed=7, progress=False)
    S1, ST = f.analytic_indices()
    idx = res.indices["y"]
    assert res.n_runs == 2048 * (3 + 2)
    # the analytic value lies inside the bootstrap interval (widened by 2x against a 5 % unlucky draw)
    # and the interval itself is informative (half-width < 0.1)
    for key, truth in (("S1", S1), ("ST", ST)):
        err = np.abs(idx[key] - truth)
        assert np.all(err <= 2 * idx[key + "_conf"] + 1e-3), (key, idx[key], truth, idx[key + "_conf"])
        assert np.all(idx[key + "_conf"] < 0.1)
    assert res.ranking("y") == ["x1", "x2", "x3"]
    assert res.warnings == []  # N = 2048: resolved indices, nothing to warn about
    rows = read_csv_table(tmp_path / "ishigami" / "results.csv")
    assert len(rows["sample_id"]) == res.n_runs and np.array_equal(rows["sample_id"], np.arange(res.n_runs))
    assert (tmp_path / "ishigami" / "indices.csv").exists()


def test_dask_local_cluster_gives_the_same_table_as_serial():
    distributed = pytest.importorskip("distributed")
    f = Ishigami()
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as lc:
        with distributed.Client(lc) as client:
            ex = SweepExecutor(client=client)
            assert ex.kind == "dask" and ex.workers == 2
            res_dask = run_morris(f, f.problem(), 10, executor=ex, seed=3, progress=False)
        with SweepExecutor(scheduler=lc.scheduler_address) as ex2:  # the CLI's --scheduler ADDRESS path
            assert ex2.kind == "dask"
            res_addr = run_morris(f, f.problem(), 10, executor=ex2, seed=3, progress=False)
    np.testing.assert_array_equal(res_addr.table["y"], res_dask.table["y"])
    res_serial = run_morris(f, f.problem(), 10, executor=SweepExecutor(workers=1), seed=3, progress=False)
    np.testing.assert_array_equal(res_dask.table["y"], res_serial.table["y"])
    np.testing.assert_allclose(res_dask.indices["y"]["mu_star"], res_serial.indices["y"]["mu_star"])
    # Ishigami: x2 has zero mean effect but a large mu* (|effect|); x1 the largest mu*
    assert res_serial.indices["y"]["mu_star"][0] > res_serial.indices["y"]["mu_star"][2]


class CountingIshigami(Ishigami):
    """Ishigami that logs the points it evaluates and is slow enough to be interrupted."""

    def __init__(self, log, delay=0.0):
        super().__init__()
        self.log, self.delay = str(log), delay

    def __call__(self, X):
        time.sleep(self.delay)
        with open(self.log, "a") as fh:
            for row in X:
                fh.write(json.dumps(list(row)) + "\n")
        return super().__call__(X)


_CHILD = textwrap.dedent("""
    import sys, numpy as np
    sys.path.insert(0, {testdir!r})
    from test_sensitivity_global_executor import CountingIshigami
    from udrobot_ctrl.sensitivity.executor import SweepExecutor, run_sweep
    from udrobot_ctrl.sensitivity.results import ResultStore
    X = np.load({design!r})
    store = ResultStore({out!r}, {{"method": "test"}}, X, ["x1", "x2", "x3"], resume=True)
    run_sweep(CountingIshigami({log!r}, delay=0.05), X, executor=SweepExecutor(workers=1), store=store,
              chunk_size=8, progress=False)
""")


@pytest.mark.slow
def test_resume_after_a_killed_sweep_recomputes_only_missing_samples(tmp_path):
    X = np.random.default_rng(0).uniform(-np.pi, np.pi, (400, 3))
    np.save(tmp_path / "design_in.npy", X)
    out = tmp_path / "study"
    ResultStore(out, {"method": "test"}, X, ["x1", "x2", "x3"]).close()  # create the study directory
    code = _CHILD.format(testdir=os.path.dirname(__file__), design=str(tmp_path / "design_in.npy"), out=str(out),
                         log=str(tmp_path / "first.log"))
    proc = subprocess.Popen([sys.executable, "-c", code])
    deadline = time.time() + 60
    while len(list((out / "chunks").glob("c*.csv"))) < 5 and time.time() < deadline and proc.poll() is None:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)  # hard interruption: no cleanup handlers run (the kernel drops its lock)
    proc.wait()
    store = ResultStore(out, {"method": "test"}, X, ["x1", "x2", "x3"], resume=True)
    (out / "chunks" / ".c99999999-0008.csv.123.0123456789ab.tmp").write_text("sample_id,x1\n5,0.1")  # half-written
    done_before = store.finished_ids()
    assert 0 < len(done_before) < len(X)
    table = store.table()  # the interrupted table is readable and consistent
    np.testing.assert_array_equal(table["sample_id"], done_before)
    np.testing.assert_allclose(table["y"], Ishigami()(X[done_before])["y"])

    log = tmp_path / "second.log"
    store = ResultStore(out, {"method": "test"}, X, ["x1", "x2", "x3"], resume=True)
    final = run_sweep(CountingIshigami(log), X, executor=SweepExecutor(workers=1), store=store, chunk_size=8,
                      progress=False)
    recomputed = np.array([json.loads(line) for line in log.read_text().splitlines()])
    expected = X[np.setdiff1d(np.arange(len(X)), done_before)]
    assert len(recomputed) == len(expected)
    np.testing.assert_array_equal(np.sort(recomputed, axis=0), np.sort(expected, axis=0))
    np.testing.assert_array_equal(final["sample_id"], np.arange(len(X)))
    np.testing.assert_allclose(final["y"], Ishigami()(X)["y"])


def test_existing_study_is_never_overwritten_and_mismatch_is_refused(tmp_path):
    X = np.zeros((4, 3))
    ResultStore(tmp_path / "s", {"method": "a"}, X, ["x1", "x2", "x3"])
    with pytest.raises(FileExistsError, match="--resume"):
        ResultStore(tmp_path / "s", {"method": "a"}, X, ["x1", "x2", "x3"])
    with pytest.raises(ValueError, match="differs"):
        ResultStore(tmp_path / "s", {"method": "a"}, X + 1, ["x1", "x2", "x3"], resume=True)


def test_failed_chunk_becomes_per_sample_errors_not_a_crash():
    def boom(X):
        raise FloatingPointError("diverged")

    out = run_sweep(boom, np.zeros((5, 2)), executor=SweepExecutor(workers=1), progress=False)
    assert list(out["sample_id"]) == [0, 1, 2, 3, 4]
    assert all("diverged" in e for e in out["error"])


def test_monte_carlo_mean_of_ishigami(tmp_path):
    from udrobot_ctrl.sensitivity.global_ import run_monte_carlo

    f = Ishigami()
    res = run_monte_carlo(f, f.problem(), 20000, executor=SweepExecutor(workers=1), out=tmp_path / "mc",
                          progress=False, chunk_size=5000)
    # E[f] = a/2 (E[sin^2 x2] = 1/2, the other terms have zero mean); std of the mean ~ 3.7/sqrt(20000)
    assert res.summary["y"]["mean"] == pytest.approx(3.5, abs=0.1)
    assert (tmp_path / "mc" / "summary.csv").exists()


def test_rank_transform_keeps_the_ishigami_ordering():
    f = Ishigami()
    res = run_sobol(f, f.problem(), 512, executor=SweepExecutor(workers=1), seed=2, progress=False, transform="rank")
    st = res.indices["y"]["ST"]
    assert np.all(np.isfinite(st)) and st[0] > st[2] > 0.05 and st[1] > 0.2
    with pytest.raises(ValueError, match="transform"):
        run_sobol(f, f.problem(), 8, executor=SweepExecutor(workers=1), transform="log")


_HOLDER = textwrap.dedent("""
    import sys, time
    from udrobot_ctrl.sensitivity.results import StudyLock
    with StudyLock({out!r}):
        print("locked", flush=True)
        time.sleep(60)
""")


@pytest.mark.slow
def test_a_second_run_on_a_locked_study_folder_fails_at_once(tmp_path, capsys):
    from udrobot_ctrl.cli import main
    from udrobot_ctrl.sensitivity.results import StudyLockedError

    out = tmp_path / "study"
    proc = subprocess.Popen([sys.executable, "-c", _HOLDER.format(out=str(out))], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "locked"
        t0 = time.perf_counter()
        with pytest.raises(StudyLockedError, match=rf"{out}.*pid {proc.pid}"):
            ResultStore(out, {"method": "a"}, np.zeros((4, 3)), ["x1", "x2", "x3"])
        assert time.perf_counter() - t0 < 5  # fails at once, does not wait
        f = Ishigami()
        with pytest.raises(StudyLockedError):
            run_morris(f, f.problem(), 2, executor=SweepExecutor(workers=1), out=out, progress=False)
        argv = ["sensitivity", "--method", "morris", "--samples", "2", "--params", "surge.CD", "--workers", "1",
                "--out", str(out), "--quiet"]
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert f"pid {proc.pid}" in err and "in use" in err and "Traceback" not in err
        assert not (out / "study.json").exists()  # nothing written by the refused runs
    finally:
        proc.kill()
        proc.wait()
    with ResultStore(out, {"method": "a"}, np.zeros((4, 3)), ["x1", "x2", "x3"]):  # holder gone: the lock is free
        pass


def test_resume_refuses_another_seed_and_keeps_a_live_writers_temp_files(tmp_path):
    f = Ishigami()
    out = tmp_path / "s"
    run_sobol(f, f.problem(), 8, executor=SweepExecutor(workers=1), out=out, seed=0, progress=False)
    with pytest.raises(ValueError, match=r"seed: stored 0, requested 1"):
        run_sobol(f, f.problem(), 8, executor=SweepExecutor(workers=1), out=out, seed=1, resume=True, progress=False)
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        mine = out / "chunks" / f".c00000000-0008.csv.{live.pid}.a1b2c3d4e5f6.tmp"  # a running writer's temp file
        mine.write_text("sample_id\n")
        dead = out / "chunks" / ".c00000008-0008.csv.999999999.d4e5f6a7b8c9.tmp"  # its writer is gone
        dead.write_text("sample_id\n")
        run_sobol(f, f.problem(), 8, executor=SweepExecutor(workers=1), out=out, seed=0, resume=True, progress=False)
        assert mine.exists() and not dead.exists()
    finally:
        live.kill()
        live.wait()


def test_sobol_with_seed_0_is_reproducible_and_a_tiny_sample_warns():
    f = Ishigami()
    runs = []
    for _ in range(2):
        with pytest.warns(RuntimeWarning, match="N = 16 < 64"):
            runs.append(run_sobol(f, f.problem(), 16, executor=SweepExecutor(workers=1), seed=0, progress=False))
        np.random.seed(len(runs))  # noqa: NPY002 - the legacy global state SALib fell back on must not matter
    a, b = (r.indices["y"] for r in runs)
    for k in ("S1", "S1_conf", "ST", "ST_conf"):
        np.testing.assert_array_equal(a[k], b[k])
    assert any("N = 16" in w for w in runs[0].warnings)


@pytest.mark.slow
def test_the_lock_ends_with_the_run_not_with_its_pool_workers(tmp_path):
    from udrobot_ctrl.sensitivity.results import StudyLock

    f = Ishigami()
    with SweepExecutor(workers=2) as ex:  # the workers are forked while the study holds its lock
        run_morris(f, f.problem(), 4, executor=ex, out=tmp_path / "a", progress=False)
        probe = subprocess.run([sys.executable, "-c", _HOLDER.format(out=str(tmp_path / "a")).replace(
            "time.sleep(60)", "pass")], capture_output=True, text=True, timeout=60)
        assert probe.stdout.strip() == "locked", probe.stderr  # another process may take it while workers live
        with StudyLock(tmp_path / "a"):
            pass
