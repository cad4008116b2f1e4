"""Fuzz target ``c-bus``: the C firmware's servo-bus layer (Feetech STS and Dynamixel Protocol 2.0) and board
core under libFuzzer, the fuzzed bytes being the bus's answers.

``python -m firmware_sim.cfirmware.fuzz_bus [libFuzzer args]`` builds the target with Debian's clang
(``-fsanitize=fuzzer,address,undefined``, :mod:`firmware_sim.cfirmware.build` kind ``fuzz-c-bus``, cached)
and replaces itself with it, so ``ghostshell fuzz c-bus`` drives it like the other targets. Input: byte 0
picks the protocol (bit 0: STS / Dynamixel 2.0) and the ESTOP torque (bit 1: hold / limp), 16 bytes of host
script (frames anywhere in the wire's range, ESTOP, ESTOP_CLEAR), then one op per packet the firmware sends
(well-formed answers with fuzzed data and error bytes, corrupted ones, raw garbage, silence); layout and
invariants in firmware_sim/c/tests/fuzz_c_bus.c (no memory error or UB, every goal sent inside its servo's
step range, commands inside the joint ranges, torque only from a known position, ESTOP holds).
:func:`load` runs one input through the binary, :func:`replay` a whole corpus in one process (the replay tests).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from firmware_sim.cfirmware import libfuzzer

__all__ = ["binary", "load", "replay"]

KIND = "fuzz-c-bus"


def binary() -> Path:
    return libfuzzer.binary(KIND)


def replay(paths: Sequence[Path]) -> None:
    """Every input in ``paths`` through the binary, one process for all (the corpus replay test)."""
    libfuzzer.replay_files(KIND, "c-bus", paths)


def load(instrument: bool = False) -> Callable[[bytes], None]:
    return libfuzzer.one_input_runner(KIND, "c-bus")


if __name__ == "__main__":
    libfuzzer.exec_target(KIND)
