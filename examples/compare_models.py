"""Reproduce the design-on-A / fly-on-B comparison (the tables and plots of ``udrobot-ctrl compare``).

    python examples/compare_models.py [OUT_DIR] [--quick] [--controllers lqr,pid]

Equivalent to ``udrobot-ctrl compare --out OUT_DIR --json OUT_DIR/compare.json``.
"""
import json
import sys
from pathlib import Path

from udrobot_ctrl.control.compare import compare, text_table, write_outputs
from udrobot_ctrl.control.missions import CONTROLLER_KINDS


def main(argv):
    out = Path(next((a for a in argv if not a.startswith("--") and "," not in a), "compare_out"))
    ctrl = next((a.split("=", 1)[1] for a in argv if a.startswith("--controllers=")), ",".join(CONTROLLER_KINDS))
    result = compare(controllers=ctrl.split(","), quick="--quick" in argv, keep_trajectories=True)
    print(text_table(result.results, result.ekf))
    files = write_outputs(result, out)
    (out / "compare.json").write_text(json.dumps(result.to_json(), indent=1))
    print(f"{len(files) + 1} files in {out} ({result.wall_s:.1f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
