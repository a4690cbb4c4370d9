"""The demo's index names what it wrote (and only that) and says the identification data are synthetic."""
from __future__ import annotations

from udrobot_ctrl.cli.demo import SYNTHETIC_NOTE, write_index


def test_index_lists_written_files_only_and_flags_synthetic_data(tmp_path):
    (tmp_path / "compare").mkdir()
    (tmp_path / "compare" / "compare_missions.png").write_bytes(b"png")
    (tmp_path / "compare" / "compare_iae_lqr.png").write_bytes(b"png")
    (tmp_path / "identification" / "raw" / "spring").mkdir(parents=True)
    path = write_index(tmp_path, failed=["open_loop"])
    text = path.read_text()
    assert path == tmp_path / "README.md"
    assert "SYNTHETIC" in text and SYNTHETIC_NOTE in text
    assert "[compare/compare_missions.png](compare/compare_missions.png)" in text
    assert "[compare/compare_iae_lqr.png](compare/compare_iae_lqr.png)" in text
    assert "[identification/raw/](identification/raw/)" in text
    assert "open_loop_surge.png" not in text  # not written, not listed
    assert "Failed steps:** open_loop" in text
    # what to open first comes first
    assert text.index("compare_missions.png") < text.index("compare_iae_lqr.png")


def test_index_lists_every_file_in_the_folder(tmp_path):
    """Every file the demo writes (compare's own list of names, the identification and model files, anything else
    that lands in the folder) is linked from the index, or lies under a linked folder."""
    import re

    from udrobot_ctrl.control.compare import output_names
    from udrobot_ctrl.control.missions import CONTROLLER_KINDS

    written = [f"compare/{n}" for n in [*output_names(CONTROLLER_KINDS), "compare.json"]]
    written += ["open_loop_surge.png", "demo_summary.json", "models/cfd_chin.json", "identification/plots/"
                "cfd_regressions.png", "identification/plots/spring_surge_fits.png", "identification/plots/"
                "pendulum_heave_vs_reynolds.png", "identification/spring_report.json",
                "identification/cfd_identified.toml", "identification/raw/spring/spring_surge_L1_r1.csv",
                "somewhere/new_file.txt"]
    for rel in written:
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("x")
    text = write_index(tmp_path).read_text()
    links = set(re.findall(r"\]\(([^)]+)\)", text))
    for path in tmp_path.rglob("*"):
        rel = path.relative_to(tmp_path).as_posix()
        if path.is_dir() or rel == "README.md":
            continue
        assert rel in links or any(rel.startswith(link) for link in links if link.endswith("/")), rel
    assert "compare/compare_ekf.csv" in links and "compare/compare_full.json" in links  # the two it used to omit
    assert "somewhere/new_file.txt" in links  # an undescribed file is still listed
    assert text.count("compare/compare_ekf.csv)") == 1  # each file listed once
    assert "see the mission's reference" in text  # the MPCs' preview is explained next to the missions plot


def test_open_loop_plot_marks_where_a_model_pitch_diverges(tmp_path, monkeypatch):
    """Issue 42: free_decay:morison's pitch runs away under full thrust; the plot marks where, on both panels."""
    import numpy as np

    from udrobot_ctrl.cli import demo

    figures = []
    monkeypatch.setattr(demo, "save_figure", lambda fig, path, **kw: figures.append(fig))
    result = demo.step_open_loop(tmp_path)
    diverged = {n for n, r in result.items() if r["max_pitch_deg"] > demo.PITCH_DIVERGED_DEG}
    assert "free_decay:morison" in diverged and len(diverged) < len(result)
    ax_u, ax_pitch = figures[0].axes[:2]
    marks = {line.get_label().rsplit(": ", 1)[0]: line for line in ax_u.get_lines() if line.get_label().endswith(
        "pitch diverges")}
    assert set(marks) == diverged  # marked exactly where the console says it diverges
    for name in diverged:
        t_mark = float(np.ravel(marks[name].get_xdata())[0])
        assert t_mark == result[name]["pitch_diverges_at_s"]
        curve = next(line for line in ax_pitch.get_lines() if line.get_color() == marks[name].get_color()
                     and len(line.get_xdata()) > 1)
        t, pitch = np.asarray(curve.get_xdata()), np.asarray(curve.get_ydata())
        first = t[np.flatnonzero(np.abs(pitch) > demo.PITCH_DIVERGED_DEG)[0]]
        assert first == t_mark  # the mark sits at the first sample past the threshold
    assert any("Munk" in text.get_text() for text in ax_u.texts)
