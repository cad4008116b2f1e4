"""Fuzz target ``c-can``: CAN frames into the C firmware's CAN link and board core under libFuzzer.

``python -m firmware_sim.cfirmware.fuzz_can [libFuzzer args]`` builds the target with Debian's clang
(``-fsanitize=fuzzer,address,undefined``, :mod:`firmware_sim.cfirmware.build` kind ``fuzz-c-can``, cached) and
replaces itself with it, so ``ghostshell fuzz c-can`` drives it like the other targets. The input layout
(firmware_sim/c/tests/fuzz_c_can.c) is the ``can-decoder`` target's frame records (so its corpus seeds this
one) after an options byte (CAN FD link; how many writes in a row the bus refuses, as SocketCAN's ENOBUFS), plus a
record that sends a fuzzed payload as the host would (its fixed frames or an ISO-TP unit), so inputs get past the
CRCs to the board core. Invariants: no memory error or UB, commands and goals inside the servo table's ranges,
ESTOP holds, every queue within its size, every frame the board sends a well-formed one of its own identifiers.
:func:`load` runs one input through the binary, :func:`replay` a whole corpus in one process (the replay tests).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

from firmware_sim.cfirmware import libfuzzer

__all__ = ["KIND", "binary", "load", "replay"]

KIND = "fuzz-c-can"


def binary() -> Path:
    """The target's executable (built on first use)."""
    return libfuzzer.binary(KIND)


def replay(paths: Sequence[Path]) -> None:
    """Every input in ``paths`` through the binary, one process for all (the corpus replay test)."""
    libfuzzer.replay_files(KIND, "c-can", paths)


def load(instrument: bool = False) -> Callable[[bytes], None]:
    """The one-input function: runs ``data`` through the binary, ``AssertionError`` when it breaks an invariant."""
    return libfuzzer.one_input_runner(KIND, "c-can")


if __name__ == "__main__":
    libfuzzer.exec_target(KIND)
