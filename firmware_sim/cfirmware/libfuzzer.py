"""What every C libFuzzer target shares: its binary (a :mod:`firmware_sim.cfirmware.build` kind, cached),
one input run through it, a whole corpus run through one process (the replay tests: the sanitized
binary takes ~0.3 s to start under load, so one process per input made a 12-input corpus take 3.6 s and
one process for all 0.7 s), and ``python -m`` replacing itself with it.

Each target module (:mod:`firmware_sim.cfirmware.fuzz_wire`, :mod:`firmware_sim.cfirmware.fuzz_bus`) names its
build kind and documents its input layout; the clang target itself checks the invariants and exits non-zero
(a sanitizer report or an invariant message on stderr) when one breaks.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import NoReturn

__all__ = ["binary", "exec_target", "one_input_runner", "replay_files"]


def binary(kind: str) -> Path:
    """The target's executable for the default robot (built with Debian's clang on first use)."""
    from firmware_sim.cfirmware.build import build
    from robots.registry import DEFAULT_ROBOT, load_robot

    return build(kind, load_robot(DEFAULT_ROBOT))


def one_input_runner(kind: str, name: str) -> Callable[[bytes], None]:
    """A function running one input through target ``kind`` as its own process; raises ``AssertionError``
    (the last 3 000 characters of its stderr) when it exits non-zero."""
    exe = binary(kind)

    def one_input(data: bytes) -> None:
        with tempfile.NamedTemporaryFile(prefix=f"{name}-", delete=False) as f:
            f.write(data)
        try:
            r = subprocess.run([str(exe), f.name], capture_output=True, text=True, timeout=60)
        finally:
            os.unlink(f.name)
        if r.returncode != 0:
            raise AssertionError(f"{name}: the C firmware broke an invariant or a sanitizer fired:\n{r.stderr[-3000:]}")

    return one_input


def replay_files(kind: str, name: str, paths: Sequence[Path], timeout_s: float = 600.0) -> None:
    """Run every input file in ``paths`` once through target ``kind``, all in one process (libFuzzer runs
    each file named on its command line); raises ``AssertionError`` naming the input it stopped at (and
    the last 3 000 characters of its stderr) when the binary exits non-zero."""
    if not paths:
        return
    r = subprocess.run([str(binary(kind)), *map(str, paths)], capture_output=True, text=True, errors="replace",
                       timeout=timeout_s)
    if r.returncode != 0:
        running = [line.split(":", 1)[1].strip() for line in r.stderr.splitlines() if line.startswith("Running:")]
        at = running[-1] if running else "?"
        raise AssertionError(f"{name}: input {at}: the C firmware broke an invariant or a sanitizer fired "
                             f"(exit {r.returncode}):\n{r.stderr[-3000:]}")


def exec_target(kind: str) -> NoReturn:
    """Replace this process with target ``kind``, libFuzzer's arguments passed on (``ghostshell fuzz``)."""
    exe = binary(kind)
    sys.stdout.flush()
    os.execv(str(exe), [str(exe), *sys.argv[1:]])
