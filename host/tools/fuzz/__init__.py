"""Coverage-guided fuzz targets (atheris / libFuzzer) and the ``ghostshell fuzz`` driver.

Each target is a module with ``load(instrument: bool) -> Callable[[bytes], None]`` (the one-input
function; it raises ``AssertionError`` when an invariant breaks) and a ``__main__`` that hands it to
atheris. ``ghostshell fuzz`` starts the module as a subprocess (libFuzzer owns the process: it exits
on the first crash), so the CLI never imports a target. The board target lives in
``firmware_sim.fuzz`` because the host never imports the board; the C firmware's in
``firmware_sim.cfirmware`` (``c-wire``, ``c-bus`` and ``c-can`` exec a clang libFuzzer binary, ``c-diff`` is atheris over both
decoders).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["FuzzTarget", "TARGETS"]


@dataclass(frozen=True)
class FuzzTarget:
    """A fuzz target: its CLI name, the module run with ``python -m`` and what it checks."""

    name: str
    module: str
    help: str


TARGETS: dict[str, FuzzTarget] = {
    t.name: t
    for t in (
        FuzzTarget(
            "serial-decoder",
            "host.tools.fuzz.serial_decoder",
            "bytes in arbitrary chunks into protocol.framing.FrameDecoder: bounded buffer, resync at the "
            "next 0x00, every frame re-encodes to its own bytes, chunking never changes the result",
        ),
        FuzzTarget(
            "board",
            "firmware_sim.fuzz",
            "valid-CRC host messages with fuzzed fields and order into the lockstep board core: never "
            "raises, targets inside joint and speed limits, frames only inside their window, bounded "
            "buffers, ESTOP always wins",
        ),
        FuzzTarget(
            "shell",
            "host.tools.fuzz.shell",
            "fuzzed text in fuzzed chunks into the function-token parser + mapper (strict and lenient): "
            "no stray exception, every mapped call satisfies its declared types and ranges, bounded state",
        ),
        FuzzTarget(
            "can-decoder",
            "host.tools.fuzz.can_decoder",
            "arbitrary CAN frames (ids, DLCs, FD, 29-bit, remote) into the CAN reassembly/decoder and ISO-TP: "
            "no partial message surfaces, surfaced messages re-encode to their frames, bounded state",
        ),
        FuzzTarget(
            "c-wire",
            "firmware_sim.cfirmware.fuzz_wire",
            "the C firmware's link decoder + board session (clang -fsanitize=fuzzer,address,undefined, lockstep, "
            "emulated bus): no memory error or UB, buffers within their sizes, commands inside the servo table's "
            "ranges, ESTOP holds",
        ),
        FuzzTarget(
            "c-can",
            "firmware_sim.cfirmware.fuzz_can",
            "CAN frames (ids, DLC, FD, 29-bit, remote, ISO-TP sequences, fuzzed messages sent as the host would) into "
            "the C firmware's CAN link + board core (clang -fsanitize=fuzzer,address,undefined, lockstep, refused "
            "writes): no memory error or UB, bounded queues, commands inside the servo table's ranges, ESTOP holds, "
            "every frame it sends well-formed",
        ),
        FuzzTarget(
            "c-diff",
            "firmware_sim.cfirmware.fuzz_diff",
            "the same bytes into the C and the Python frame decoders (Python chunked): the same frames (bytes and "
            "decoded fields) and errors out",
        ),
        FuzzTarget(
            "bus-sts",
            "firmware_sim.servobus.fuzz_sts",
            "garbage, partial and mutated Feetech STS status packets as the servo bus's answers to the board's motor "
            "bus + safety layer (scservo_sdk on an in-memory port): no exception, bounded state, one goal SYNC WRITE "
            "a tick, every goal inside its servo's calibrated step limits",
        ),
        FuzzTarget(
            "bus-dxl2",
            "firmware_sim.servobus.fuzz_dxl2",
            "the same for Dynamixel Protocol 2.0 (dynamixel_sdk, indirect addressing, hardware error status): no "
            "exception, bounded state, one goal SYNC WRITE a tick, every goal inside its step limits",
        ),
        FuzzTarget(
            "c-bus",
            "firmware_sim.cfirmware.fuzz_bus",
            "fuzzed servo-bus answers (byte 0: Feetech STS or Dynamixel 2.0, ESTOP hold/limp; well-formed, corrupted, "
            "garbage, silence) into the C firmware's bus layer and board core (clang -fsanitize=fuzzer,address,undefined, "
            "lockstep): no memory error or UB, every goal sent inside its servo's step range, commands inside the joint "
            "ranges, torque only from a known position, ESTOP holds",
        ),
        FuzzTarget(
            "session",
            "host.tools.fuzz.link_receive",
            "fuzzed board replies into the link client's receive path: no exception, bounded maps, "
            "counters consistent",
        ),
    )
}
