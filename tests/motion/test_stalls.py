"""Stall injection (``GHOSTSHELL_STALLS``, :mod:`host.motion.stalls`): off unless set, seeded, and a bad
value is one line and exit code 2."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from host.motion.stalls import ENV, parse

ROOT = Path(__file__).resolve().parents[2]


def test_a_value_gives_seeded_stalls() -> None:
    a, b = parse("seed=3,p=0.5,max_s=0.2"), parse(" max_s=0.2 , p=0.5, seed=3 ")
    assert (a.p, a.max_s) == (0.5, 0.2)
    assert [a.rng.random() for _ in range(5)] == [b.rng.random() for _ in range(5)]  # the same draws


@pytest.mark.parametrize("bad", ["seed=x", "p=2", "max_s=-1", "speed=3", "p"])
def test_a_bad_value_is_refused(bad: str) -> None:
    with pytest.raises(ValueError, match=ENV):
        parse(bad)


def test_off_by_default_and_a_bad_environment_is_one_line_and_exit_2() -> None:
    code = "import host.motion.stalls as s; print(s.STALLS)"
    env = {k: v for k, v in os.environ.items() if k != ENV}
    off = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT, timeout=60)
    assert off.returncode == 0 and off.stdout.strip() == "None"
    bad = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60,
                         env={**env, ENV: "p=lots"})
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.count("\n") == 1 and bad.stderr.startswith(f"ghostshell: {ENV}"), bad.stderr
