"""A dataflash FMT record whose ``TimeUS`` column name is damaged costs that message type only (issue 40, item 4:
a damaged copy of a shared log converts, or exits 2 with the reason). It used to stop the whole conversion."""
from __future__ import annotations

from pathlib import Path

import pytest

from udrobot_ctrl.convert import convert_log

SMALL_BIN = Path(__file__).resolve().parents[4] / "shared" / "data" / "ardusub_log_tools" / "small.BIN"


@pytest.mark.skipif(not SMALL_BIN.is_file(), reason="shared ArduSub logs not present")
@pytest.mark.parametrize("message", ["BAT", "IMU", "XKF1", "RATE"])
def test_a_damaged_timeus_column_name_skips_that_message_only(tmp_path, message):
    data = bytearray(SMALL_BIN.read_bytes())
    fmt = data.find(message.encode().ljust(4, b"\0"))  # the FMT record's name field (4 bytes, NUL-padded)
    col = data.find(b"TimeUS", fmt)
    assert 0 < fmt < col < fmt + 80
    data[col:col + 6] = b"TimeXS"  # one flipped byte in the column name
    path = tmp_path / "damaged.BIN"
    path.write_bytes(bytes(data))
    clean = convert_log(SMALL_BIN, "ardusub")
    run = convert_log(path, "ardusub")
    assert run.n == clean.n
    assert f"damage: no TimeUS in {message} (damaged FMT record? fields: TimeXS" in run.metadata["notes"]
