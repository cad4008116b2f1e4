"""Building and loading the native tick (firmware_sim/native) never breaks a board.

Each case runs the board core in a fresh Python subprocess (the loader caches its result
per process) with its own cache folder: no compiler, a compiler that fails, a corrupt cached library,
several processes building into one empty cache at once. The C must also be warning-clean under -Werror.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from firmware_sim.native import FLAGS, SOURCE, native_reason

ROOT = Path(__file__).resolve().parents[2]
NOTE = "native tick unavailable"

# two boards (one note per process), a few ticks each; prints which path ran
_SCRIPT = """
from firmware_sim.board import Board
from firmware_sim.config import BoardConfig
from protocol.messages import PROTOCOL_VERSION, Advance, Hello
paths = []
for _ in range(2):
    b = Board(BoardConfig(lockstep=True))
    b.handle(Hello(PROTOCOL_VERSION, b.wire_schema.hash, 0), 0)
    b.handle(Advance(20_000), 1)
    while b.can_tick():
        b.tick()
    assert b.ticks == 10, b.ticks
    paths.append("native" if b.native is not None else "python")
print(" ".join(paths))
"""


def _run(cache: Path, **env: str) -> subprocess.CompletedProcess[str]:
    full = dict(os.environ, GHOSTSHELL_NATIVE_CACHE=str(cache), PYTHONPATH=str(ROOT), **env)
    full.pop("GHOSTSHELL_BOARD_KERNEL", None)
    return subprocess.run([sys.executable, "-c", _SCRIPT], cwd=ROOT, env=full, capture_output=True, text=True,
                          timeout=300)


def _need_cc() -> None:
    if native_reason() is not None:
        pytest.fail(f"native tick unavailable here: {native_reason()} (.ci/setup installs gcc)")


def test_no_compiler_runs_the_python_path_with_one_note(tmp_path: Path) -> None:
    r = _run(tmp_path / "cache", CC=str(tmp_path / "no-such-cc"))
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["python", "python"]
    notes = [line for line in r.stderr.splitlines() if NOTE in line]
    assert len(notes) == 1 and "no C compiler" in notes[0], r.stderr


def test_a_failing_compiler_runs_the_python_path(tmp_path: Path) -> None:
    cc = tmp_path / "broken-cc"
    cc.write_text("#!/bin/sh\necho 'tick.c:1:1: error: this compiler is broken' >&2\nexit 1\n")
    cc.chmod(0o755)
    r = _run(tmp_path / "cache", CC=str(cc))
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["python", "python"]
    notes = [line for line in r.stderr.splitlines() if NOTE in line]
    assert len(notes) == 1 and "this compiler is broken" in notes[0], r.stderr
    assert not list((tmp_path / "cache").glob("*")), "a failed build leaves nothing in the cache"


def test_native_ticks_and_a_corrupt_cached_library_is_rebuilt(tmp_path: Path) -> None:
    _need_cc()
    cache = tmp_path / "cache"
    r = _run(cache)
    assert r.returncode == 0 and r.stdout.split() == ["native", "native"], r.stderr
    (lib,) = cache.glob("tick-*.so")
    lib.write_bytes(b"not an ELF file")
    r = _run(cache)
    assert r.returncode == 0 and r.stdout.split() == ["native", "native"], r.stderr
    assert NOTE not in r.stderr
    assert lib.read_bytes()[:4] == b"\x7fELF"


def test_parallel_first_builds_share_one_cache(tmp_path: Path) -> None:
    _need_cc()
    cache = tmp_path / "cache"
    env = dict(os.environ, GHOSTSHELL_NATIVE_CACHE=str(cache), PYTHONPATH=str(ROOT))
    env.pop("GHOSTSHELL_BOARD_KERNEL", None)
    procs = [subprocess.Popen([sys.executable, "-c", _SCRIPT], cwd=ROOT, env=env, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True) for _ in range(3)]
    for p in procs:
        out, err = p.communicate(timeout=300)
        assert p.returncode == 0 and out.split() == ["native", "native"], err
    assert [p.name for p in cache.iterdir()] == [next(cache.glob("tick-*.so")).name], "no temporary files left"


def test_tick_c_is_warning_clean(tmp_path: Path) -> None:
    cc = shutil.which(os.environ.get("CC") or "cc")
    if cc is None:
        pytest.fail("no C compiler (.ci/setup installs gcc)")
    r = subprocess.run([cc, *FLAGS, "-Werror", str(SOURCE), "-o", str(tmp_path / "t.so"), "-lm"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
