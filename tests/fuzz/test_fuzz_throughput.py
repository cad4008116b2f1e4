"""What the fuzz targets do to run faster keeps them checking what they checked (issue 17 item 5).

Instrumentation narrowed to the modules under test, the shell's one long-lived Trio loop, the
serial-decoder's remembered frames (a new frame is still decoded and re-encoded for real), the board
target's tick cap (the watchdog's HOLD and CROUCH still happen inside one input).
"""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("atheris", reason="the fuzz extra is not installed (pip install -e '.[fuzz]')")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent


def test_package_modules_lists_submodules_without_importing() -> None:
    from host.tools.fuzz.harness import package_modules

    names = package_modules("protocol")
    assert {"protocol", "protocol.framing", "protocol.codec", "protocol.can", "protocol.can.decoder"} <= set(names)


def test_instrument_only_instruments_just_the_named_modules() -> None:
    """atheris' own ``include`` would instrument every ``protocol`` module imported in the block."""
    code = (
        "from host.tools.fuzz.harness import instrument_only\n"
        "with instrument_only(['protocol.framing']):\n"
        "    import protocol.framing\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          check=True)
    instrumented = {line.split()[-1] for line in proc.stderr.splitlines() if line.startswith("INFO: Instrumenting")}
    assert instrumented == {"protocol.framing"}, proc.stderr


def test_trio_loop_runs_on_virtual_time_and_raises_in_the_caller() -> None:
    import math

    import trio

    from host.tools.fuzz.shell import TrioLoop

    loop = TrioLoop()

    async def nap(seconds: float) -> float:
        t0 = trio.current_time()
        await trio.sleep(seconds)
        return trio.current_time() - t0

    async def fail() -> None:
        raise AssertionError("from the loop")

    assert loop.run(nap, 600.0) == 600.0  # virtual: returns at once
    assert loop.clock.autojump_threshold == math.inf  # idle between calls: no busy polling
    with pytest.raises(AssertionError, match="from the loop"):
        loop.run(fail)
    assert loop.run(nap, 1.5) == 1.5


def test_serial_decoder_still_reencodes_a_new_frame_after_warm_up(monkeypatch: pytest.MonkeyPatch) -> None:
    """Remembered frames are the ones already checked: a frame first seen later is decoded and
    re-encoded for real, so an encoder bug on it is found (and reproduces from that input alone)."""
    import protocol.framing as framing
    from protocol.messages import Heartbeat

    seen = framing.encode_frame(Heartbeat(77), 5)
    fine = framing.encode_frame(Heartbeat(78), 5)
    real = framing.encode_frame
    monkeypatch.setattr(framing, "encode_frame",
                        lambda m, s, schema=None: b"x" if getattr(m, "sender_time_us", 0) == 77 else real(m, s, schema))
    from host.tools.fuzz.serial_decoder import load

    one_input = load(False)
    for p in sorted((HERE / "serial-decoder" / "corpus").glob("*")):
        one_input(p.read_bytes())  # the seeds' frames are remembered now
    one_input(fine + b"\0\0\0\0")  # chunking seed in the last 4 bytes (FuzzedDataProvider)
    with pytest.raises(AssertionError, match="re-encodes"):
        one_input(seen + b"\0\0\0\0")
    assert framing._decode_block.__name__ == "_decode_block"  # the memo is in place only while an input runs


def test_serial_decoder_still_finds_a_chunking_bug_on_remembered_frames(monkeypatch: pytest.MonkeyPatch) -> None:
    import protocol.framing as framing
    from host.tools.fuzz.serial_decoder import load

    one_input = load(False)
    inputs = [p.read_bytes() for p in sorted((HERE / "serial-decoder" / "corpus").glob("*"))]
    for data in inputs:
        one_input(data)
    feed = framing.FrameDecoder.feed

    def loses_a_byte_at_a_split(self: framing.FrameDecoder, data: bytes) -> list:  # type: ignore[type-arg]
        if self._buf and data:
            del self._buf[-1]
        return feed(self, data)

    monkeypatch.setattr(framing.FrameDecoder, "feed", loses_a_byte_at_a_split)
    with pytest.raises(AssertionError, match="chunking changed the result"):
        for data in inputs:
            one_input(data)


def test_board_target_reaches_hold_and_crouch_within_its_tick_budget(monkeypatch: pytest.MonkeyPatch) -> None:
    """One ADVANCE over the whole budget (no message while it runs) trips the watchdog to HOLD and
    then CROUCH inside the :data:`firmware_sim.fuzz.TICKS_PER_INPUT` ticks one input may run."""
    from firmware_sim import fuzz
    from firmware_sim.board import Board
    from firmware_sim.safety import Mode

    modes: list[Mode] = []
    tick = Board.tick

    def recording_tick(self: Board) -> list:  # type: ignore[type-arg]
        out = tick(self)
        modes.append(self.mode)
        return out

    monkeypatch.setattr(Board, "tick", recording_tick)
    one_input = fuzz.load(False)
    seq = struct.pack("<BHhH", 1, 1, 10, 1) + struct.pack("<h", 0)  # one SERVO frame arms the watchdog
    one_input(seq + bytes([2, 127]))  # then TICKS: ADVANCE by 127 ticks, one by one (>= 128 would batch them)
    assert len(modes) == fuzz.TICKS_PER_INPUT
    assert Mode.HOLD in modes and modes[-1] is Mode.CROUCH, modes
