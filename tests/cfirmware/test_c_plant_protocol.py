"""``python -m firmware_sim --firmware c --bus-protocol dxl2`` without ``--servo-bus``: the C firmware speaks
Dynamixel Protocol 2.0 to the emulated plant (the launcher's in-process plant in dxl2 mode), not STS."""

from __future__ import annotations

from pathlib import Path

from protocol.codec import SCHEMA_HASH
from protocol.messages import PROTOCOL_VERSION, Advance, Caps, Hello, Telemetry

from .wire import Wire


def test_the_c_firmware_drives_the_emulated_plant_over_dynamixel(tmp_path: Path) -> None:
    err = tmp_path / "board.stderr"
    w = Wire(["--lockstep", "--firmware", "c", "--bus-protocol", "dxl2", "--estop-torque", "limp"], err)
    try:
        w.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0))
        w.wait(lambda: bool(w.of(Caps)), what="CAPS")
        w.send(Advance(40_000))
        w.wait(lambda: any(t.board_time_us >= 40_000 for t in w.of(Telemetry)), what="telemetry")
        assert all(len(t.positions) == 12 for t in w.of(Telemetry))
    finally:
        status = w.close()
    text = err.read_text()
    assert status == 130, text[-2000:]
    assert "dxl2" in text and "servo bus (sts" not in text, text[-2000:]
