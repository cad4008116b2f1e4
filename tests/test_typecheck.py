"""The source tree type-checks cleanly under mypy."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import platformdirs
import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("protocol", "robots", "firmware_sim", "host")


def cache_dir() -> Path:
    """mypy's incremental cache, kept between runs in the user cache dir (``ghostshell/mypy``, beside the C
    builds of :mod:`firmware_sim.cfirmware.build`) rather than in the checkout's ``.mypy_cache``: a fresh
    clone on a machine that checked one before starts warm (a cold check took ~35 s, a warm one ~4 s). A
    machine with an empty cache (a CI runner made from scratch) pays the cold check once, as before.

    The verdict does not depend on the cache: mypy reuses a module's cached result only while its source
    (size, then content hash when the mtime or checkout path differ), its dependencies, mypy's version and
    the options are the same, and it reports a cached module's errors again (the test fails on a warm
    cache exactly as on a cold one)."""
    return Path(platformdirs.user_cache_dir("ghostshell")) / "mypy"


@pytest.mark.skipif(
    importlib.util.find_spec("mypy") is None,
    reason="mypy is not installed (pip install -e '.[test]' provides it)",
)
def test_mypy_reports_no_errors() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "mypy", "--ignore-missing-imports", "--cache-dir", str(cache_dir()), *PACKAGES],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=280,
        check=False,
    )
    assert proc.returncode == 0, f"mypy exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
