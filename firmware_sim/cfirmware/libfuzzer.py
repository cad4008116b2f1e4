"""What every C libFuzzer target shares: its binary (a :mod:`firmware_sim.cfirmware.build` kind, cached),
one input run through it (the replay tests), and ``python -m`` replacing itself with it.

Each target module (:mod:`firmware_sim.cfirmware.fuzz_wire`, :mod:`firmware_sim.cfirmware.fuzz_bus`) names its
build kind and documents its input layout; the clang target itself checks the invariants and exits non-zero
(a sanitizer report or an invariant message on stderr) when one breaks.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

__all__ = ["binary", "exec_target", "one_input_runner"]


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


def exec_target(kind: str) -> NoReturn:
    """Replace this process with target ``kind``, libFuzzer's arguments passed on (``ghostshell fuzz``)."""
    exe = binary(kind)
    sys.stdout.flush()
    os.execv(str(exe), [str(exe), *sys.argv[1:]])
