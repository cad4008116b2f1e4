"""The C firmware carries robots of 17..32 servos: built with the u32-mask codec (the build picks the
codec by the robot's servo count), a generated robot runs ``ghostshell run --firmware c --lockstep``
to the end, its joints reach their targets in the board's telemetry, and the frames on the wire are
the 32 schema's. 32 servos is the widest goal SYNC WRITE on the servo bus (98 parameter bytes): it
used to be dropped unsent, so the joints never moved while the program said done."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import pytest
from cobs import cobs

from firmware_sim.cfirmware.build import codec_dir
from protocol.codec import WIRE_SCHEMA_32
from protocol.framelog import LogDecoder, iter_records
from protocol.messages import Caps, ServoFrame, Telemetry
from robots.loader import load_robot_dir
from support.gen_robot import joint_name, write_chain_robot

pytestmark = pytest.mark.timeout(240)

FIRST_DEG, LAST_DEG, TOL_DEG = 20.0, -15.0, 3.0


@pytest.mark.parametrize("n", [17, 32])
def test_a_wide_robot_runs_on_the_c_firmware(tmp_path: Path, n: int) -> None:
    pkg = write_chain_robot(tmp_path, n)
    assert codec_dir(load_robot_dir(pkg)).name == "schema32"
    xml = (f'<pose name="home"/><joint_move joint="{joint_name(0)}" deg="{FIRST_DEG}"/>'
           f'<joint_move joint="{joint_name(n - 1)}" deg="{LAST_DEG}"/>')
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "host", "run", "--robot", str(pkg), "--firmware", "c", "--lockstep",
                        "--no-live", "--out", str(out), "--xml", xml], capture_output=True, text=True, cwd=tmp_path,
                       timeout=200)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    done = r.stdout.split("program: done")
    assert len(done) == 2 and "failed" not in done[1].splitlines()[0], r.stdout
    assert f"chain{n} ({n} servos), lockstep" in (out / "board.stderr").read_text() and \
        "C firmware" in (out / "board.stderr").read_text()

    dec = LogDecoder()
    caps, tel, frames = [], [], []
    with open(out / "board_frames.jsonl", encoding="utf-8") as f:
        for rec in iter_records(f):
            assert "error" not in rec, rec
            msg = dec.decode(rec["raw"]).msg  # type: ignore[union-attr]
            if isinstance(msg, Caps):
                caps.append(msg)
            elif isinstance(msg, Telemetry):
                tel.append(msg)
            elif isinstance(msg, ServoFrame):
                payload = cobs.decode(bytes.fromhex(rec["raw"])[:-1])[5:-2]
                assert len(payload) == 4 + 4 + 2 * n  # apply-at u32, mask u32, one target per servo
                assert int.from_bytes(payload[4:8], "little") == (1 << n) - 1
                frames.append(msg)
    assert caps and all(c.schema_hash == WIRE_SCHEMA_32.hash and c.servo_count == n for c in caps)
    assert dec.schema is WIRE_SCHEMA_32 and frames
    assert len(tel) > 50 and all(len(t.positions) == n for t in tel)
    want = [0.0] * n
    want[0], want[-1] = FIRST_DEG, LAST_DEG
    final = [math.degrees(q) for q in tel[-1].positions]
    assert max(abs(a - b) for a, b in zip(final, want)) < TOL_DEG, f"final joints {final} (deg), targets {want}"
