"""``ghostshell --help`` names every environment variable the commands read (host.cli.ENVIRONMENT)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from host.cli import ENVIRONMENT

ROOT = Path(__file__).resolve().parents[2]
#: set by ``ghostshell board`` / ``ghostshell firmware`` for the usage line of the module they run, never by a user
INTERNAL = {"GHOSTSHELL_BOARD_PROG", "GHOSTSHELL_FIRMWARE_PROG"}


def _read_by_the_code() -> set[str]:
    names: set[str] = set()
    for part in ("host", "firmware_sim", "robots", "protocol"):
        for path in (ROOT / part).rglob("*.py"):
            names |= set(re.findall(r"[\"'](GHOSTSHELL_[A-Z_]+)[\"']", path.read_text(encoding="utf-8")))
    return names - INTERNAL


def test_every_variable_the_code_reads_is_documented() -> None:
    read = _read_by_the_code()
    assert len(read) >= 10  # the scan finds them (it would pass vacuously on an empty set)
    assert read <= set(ENVIRONMENT), sorted(read - set(ENVIRONMENT))
    assert set(ENVIRONMENT) - {"MUJOCO_GL"} <= read, sorted(set(ENVIRONMENT) - read)  # none stale


def test_the_help_lists_them() -> None:
    out = subprocess.run([sys.executable, "-m", "host", "--help"], capture_output=True, text=True, check=True,
                         cwd=ROOT, env={"PATH": "/usr/bin:/bin", "COLUMNS": "80"}).stdout
    section = out.split("\nenvironment:\n", 1)[1]
    assert [line.split()[0] for line in section.splitlines() if line.startswith("  ") and not line.startswith("   ")] \
        == list(ENVIRONMENT)
    assert max(len(line) for line in out.splitlines()) <= 80
