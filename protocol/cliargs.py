"""Command-line argument types both ends share: ``--fault-seed`` and ``--push``.

The host's ``ghostshell run`` and the board's ``python -m firmware_sim`` accept the same two options
with the same syntax and the same error lines (a run passes them on to the board it starts), so their
``argparse`` types live once, here, beside the protocol both ends import; :mod:`protocol.faults`
stays a pure fault model with no command-line code. Each function takes the option's text and
returns its value or raises ``argparse.ArgumentTypeError`` with one line naming what is wrong.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["push_arg", "seed_arg"]


def seed_arg(text: str) -> int:
    """``--fault-seed`` on both ends' command lines: an integer >= 0 (``argparse.ArgumentTypeError`` otherwise)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be an integer >= 0, got {text}")
    return v


def push_arg(text: str) -> tuple[float, tuple[float, float, float], float]:
    """``--push S:FX,FY,FZ[:DUR]`` on both ends (emulated board only: a push on the robot's base, a
    scripted disturbance): (start board s, force N in the world frame, duration s, default 0.2).
    ``argparse.ArgumentTypeError`` names what is wrong."""
    parts = text.split(":")
    try:
        if len(parts) not in (2, 3):
            raise ValueError
        at = float(parts[0])
        force = tuple(float(v) for v in parts[1].split(","))
        dur = float(parts[2]) if len(parts) == 3 else 0.2
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected S:FX,FY,FZ[:DURATION] (seconds, newtons), got {text!r}") from None
    if len(force) != 3 or not all(math.isfinite(v) and abs(v) <= 1000 for v in force):
        raise argparse.ArgumentTypeError(f"the force needs three finite components within +-1000 N, got {text!r}")
    if not (math.isfinite(at) and at >= 0 and math.isfinite(dur) and 0 < dur <= 10):
        raise argparse.ArgumentTypeError(f"start >= 0 s and 0 < duration <= 10 s, got {text!r}")
    return at, (force[0], force[1], force[2]), dur
