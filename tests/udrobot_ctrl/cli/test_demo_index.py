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
