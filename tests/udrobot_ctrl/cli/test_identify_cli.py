"""``udrobot-ctrl identify``: end to end on synthetic protocol files, JSON contract, sets, plots, bad input."""
from __future__ import annotations

import json

import numpy as np
import pytest

from identification import cfd, synthetic
from udrobot_ctrl.cli import main
from udrobot_ctrl.vehicle import load_model


@pytest.fixture(scope="module")
def spring_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("spring")
    truth = synthetic.paper_spring_truth()
    synthetic.write_protocol(d, synthetic.protocol("spring", truth, seed=11, repeats=3), "spring")
    return d, truth


def _run(argv, capsys):
    code = main(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.slow
def test_spring_json_contract_and_set(spring_dir, tmp_path, capsys):
    d, truth = spring_dir
    bad = tmp_path / "spring_surge_L1_bad.csv"
    bad.write_text("t,y\n" + "".join(f"{0.01 * i},0.05\n" for i in range(100)))  # does not oscillate
    report_path, set_path = tmp_path / "r.json", tmp_path / "mine.toml"
    code, out, _ = _run(["identify", "spring", str(d), str(bad), "--json", str(report_path), "--out",
                         str(set_path), "--mechanical-damping", "0.5", "--plot", str(tmp_path / "plots")], capsys)
    assert code == 0
    assert "ERROR" in out and "does not oscillate" in out
    rep = json.loads(report_path.read_text())
    assert rep["method"].startswith("spring")
    assert len(rep["launches"]) == 37 and rep["n_ok"] == 36
    failed = [e for e in rep["launches"] if not e["ok"]]
    assert failed[0]["file"] == str(bad) and "does not oscillate" in failed[0]["error"]
    for e in rep["launches"]:
        assert {"file", "ok", "error"} <= set(e)
    assert set(rep["aggregate"]) == {"surge", "sway", "heave"}  # several axes: keyed by axis
    for axis, tr in truth.items():
        agg = rep["aggregate"][axis]
        for key in ("Cm", "CD", "KL", "KQ", "added_mass_kg"):
            assert set(agg[key]) >= {"value", "ci95"}
        assert agg["Cm"]["value"] == pytest.approx(tr.Cm, rel=0.02)
        assert agg["CD"]["value"] == pytest.approx(tr.CD, rel=0.05)
        assert agg["KL"]["value"] == pytest.approx(tr.mechanical_damping - 0.5, abs=0.1)  # rig damping removed
        # full scale: K_Q over the projected-area law, C_m unchanged
        fs = rep["full_scale"][axis]
        assert fs["KQ"]["value"] == pytest.approx(agg["KQ"]["value"] / 0.30 ** 2)
        assert fs["Cm"]["value"] == agg["Cm"]["value"]
    # the set loads as a model whose surge added mass is C_m x the vehicle's displaced mass
    v = load_model(f"{set_path}:morison")
    ref = rep["full_scale"]["surge"]["reference_mass"]["value"]
    assert v.added_mass[0, 0] == pytest.approx(rep["aggregate"]["surge"]["Cm"]["value"] * ref)
    assert v.quadratic_damping[0, 0] == pytest.approx(0.5 * 1000 * rep["aggregate"]["surge"]["CD"]["value"] * 0.04938,
                                                      rel=1e-3)
    plots = sorted(p.name for p in (tmp_path / "plots").glob("*.png"))
    assert "spring_surge_fits.png" in plots and "spring_heave_vs_reynolds.png" in plots


def test_single_axis_aggregate_is_flat_and_graphical(spring_dir, tmp_path, capsys):
    d, truth = spring_dir
    files = sorted(str(p) for p in d.glob("spring_heave_*.csv"))
    rp = tmp_path / "h.json"
    code, _, _ = _run(["identify", "spring", *files, "--fit", "graphical", "--json", str(rp), "--quiet"], capsys)
    assert code == 0
    rep = json.loads(rp.read_text())
    assert "graphical" in rep["method"]
    # graphical C_m from period and decrement is unbiased; its C_D lumps the rig damping into the fluid
    assert rep["aggregate"]["Cm"]["value"] == pytest.approx(truth["heave"].Cm, rel=0.03)
    assert rep["aggregate"]["CD"]["value"] > truth["heave"].CD
    groups = {e["group"] for e in rep["launches"]}
    assert groups == {"L1", "L2", "L3", "L4"}
    assert all(set(t["groups"]) <= groups for t in rep["pairwise"]["Cm"])


def test_pendulum_requires_length_and_cfd_set_with_base(tmp_path, capsys):
    truth = synthetic.paper_pendulum_truth()
    files = synthetic.write_protocol(tmp_path / "p", synthetic.protocol("pendulum", truth, seed=2, axes=("sway",),
                                                                        repeats=2), "pend")
    code, _, err = _run(["identify", "pendulum", *map(str, files)], capsys)
    assert code == 2 and "--length" in err
    rp = tmp_path / "p.json"
    code, _, _ = _run(["identify", "pendulum", *map(str, files), "--length", "0.30", "--json", str(rp), "--quiet"],
                      capsys)
    rep = json.loads(rp.read_text())
    assert rep["aggregate"]["KQ"]["value"] == pytest.approx(truth["sway"].KQ, rel=0.05)
    assert rep["aggregate"]["KL"]["value"] == pytest.approx(truth["sway"].KL, rel=0.2)
    assert "morison" in rep["aggregate"]
    # CFD tables, one per axis; without --base the set lacks added mass and is refused
    paths = []
    for axis, (kl, kq) in zip(("surge", "sway", "heave"), ((1.0503, 43.2322), (0.5706, 28.7941), (0.1306, 58.5848))):
        u, f = cfd.synthetic_table(kl, kq)
        p = tmp_path / f"cfd_{axis}.csv"
        np.savetxt(p, np.column_stack([u, f]), delimiter=",", header="speed,force", comments="")
        paths.append(str(p))
    out = tmp_path / "cfd_mine.toml"
    code, _, err = _run(["identify", "cfd", *paths, "--out", str(out), "--quiet"], capsys)
    assert code == 2 and "added_mass" in err and not out.exists()
    code, _, _ = _run(["identify", "cfd", *paths, "--out", str(out), "--base", "pendulum", "--quiet"], capsys)
    assert code == 0
    v = load_model(f"{out}:chin")
    assert np.diag(v.linear_damping)[:3] == pytest.approx([1.0503, 0.5706, 0.1306], rel=1e-6)
    assert v.added_mass[0, 0] == pytest.approx(8.3027)  # borrowed from the base set
    assert "assumed" in v.provenance["added_mass[0][0]"]


def test_never_overwrites_inputs(spring_dir, capsys):
    d, _ = spring_dir
    f = sorted(d.glob("*.csv"))[0]
    before = f.read_bytes()
    code, _, err = _run(["identify", "spring", str(f), "--json", str(f)], capsys)
    assert code == 2 and "overwrite" in err
    assert f.read_bytes() == before
