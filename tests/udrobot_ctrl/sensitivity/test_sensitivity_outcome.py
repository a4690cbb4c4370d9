"""``sensitivity`` says when a study did not run as asked (issue 40, item 7): failed evaluations, fewer runs than
requested, a --samples it would not use, and a plain tcp:// dask scheduler."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import udrobot_ctrl.cli.sensitivity as sens_cli
import udrobot_ctrl.sensitivity.global_ as global_
from udrobot_ctrl.cli.main import main
from udrobot_ctrl.sensitivity.executor import SweepExecutor, scheduler_warning
from udrobot_ctrl.sensitivity.global_ import StudyIncompleteError, run_morris


class FailingEvaluator:
    """A cheap stand-in for the mission evaluator: metric = sum of the parameters; samples whose first parameter is
    above ``threshold`` fail with an error (as a design that does not converge would)."""

    def __init__(self, space, threshold):
        self.space, self.threshold = space, threshold

    def __call__(self, X):
        X = np.asarray(X, float)
        lo, hi = self.space.bounds[0]
        bad = (X[:, 0] - lo) / (hi - lo) > self.threshold
        y = np.where(bad, np.nan, X.sum(axis=1))
        return {"iae": y, "error": ["design failed: not converged" if b else "" for b in bad]}

    def describe(self) -> str:
        return f"failing(threshold={self.threshold})"


ARGV = ["sensitivity", "--model", "pendulum:chin", "--method", "morris", "--samples", "4", "--params",
        "surge.KQ,heave.KQ", "--workers", "1", "--quiet"]


@pytest.mark.parametrize("threshold, status, words", [
    (np.inf, 0, None),
    (0.0, 1, "runs failed (first: design failed: not converged)"),
    (-np.inf, 2, "every run failed"),
])
def test_failed_evaluations_are_reported_with_the_exit_status(monkeypatch, capsys, threshold, status, words):
    monkeypatch.setattr(sens_cli, "build_evaluator", lambda args, space: FailingEvaluator(space, threshold))
    assert main(ARGV) == status
    err = capsys.readouterr().err
    if words is None:
        assert "not run as asked" not in err
    else:
        assert words in err and "study not run as asked" in err and f"(exit status {status})" in err


def test_fewer_runs_than_requested_is_an_error(monkeypatch, tmp_path):
    real = global_.run_sweep

    def lossy(evaluator, X, **kwargs):  # a backend that lost a chunk
        table = real(evaluator, X, **kwargs)
        return {k: np.asarray(v)[:-3] for k, v in table.items()}

    monkeypatch.setattr(global_, "run_sweep", lossy)
    space = {"num_vars": 2, "names": ["a", "b"], "bounds": [[0.0, 1.0], [0.0, 1.0]]}
    with pytest.raises(StudyIncompleteError, match=r"morris study incomplete: 9 of the 12 requested runs"):
        run_morris(lambda X: {"y": np.asarray(X).sum(axis=1)}, space, 4, executor=SweepExecutor(workers=1),
                   progress=False, chunk_size=100)


def test_samples_zero_is_refused_and_local_says_it_ignores_samples(capsys, monkeypatch):
    assert main([*ARGV[:4], "sobol", "--samples", "0", "--workers", "1"]) == 2
    assert "--samples must be a positive number" in capsys.readouterr().err
    monkeypatch.setattr(sens_cli, "build_evaluator", lambda args, space: FailingEvaluator(space, np.inf))
    argv = ["sensitivity", "--model", "pendulum:chin", "--method", "local", "--samples", "64", "--params",
            "surge.KQ", "--workers", "1", "--quiet"]
    assert main(argv) == 0
    assert "--samples 64 is not used by --method local" in capsys.readouterr().err


HOSTS = st.one_of(st.sampled_from(["localhost", "127.0.0.1", "10.0.0.5", "sched.example.org", "[::1]", "0.0.0.0"]),
                  st.from_regex(r"[a-z][a-z0-9-]{0,12}(\.[a-z]{2,5})?", fullmatch=True))


@settings(max_examples=80, deadline=None)
@given(protocol=st.sampled_from(["tcp://", "TCP://", "", "ws://", "tls://", "TLS://", "wss://", "inproc://"]),
       host=HOSTS, port=st.integers(1, 65535))
def test_plain_schedulers_are_warned_about_and_tls_is_not(protocol, host, port):
    address = f"{protocol}{host}:{port}"
    note = scheduler_warning(address)
    if protocol.lower() in ("tls://", "wss://", "inproc://"):
        assert note is None
    else:
        assert note is not None and address in note and "unencrypted" in note and f"tls://{host}:{port}" in note


def test_the_cli_warns_before_connecting_to_a_plain_scheduler(capsys, monkeypatch):
    """The warning comes before the connection (here refused at once)."""
    def refuse(*args, **kwargs):
        raise ValueError("cannot connect to dask scheduler (test)")

    monkeypatch.setattr(sens_cli, "SweepExecutor", refuse)
    assert main(ARGV + ["--scheduler", "tcp://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err
    assert err.index("warning: scheduler tcp://127.0.0.1:9: tcp:// is unencrypted") < err.index("error:")
