"""Progress bars (rich) on a terminal only: output to a pipe is unchanged, ``--quiet`` drops the progress."""

from __future__ import annotations

import io
import os
import pty
import re
import subprocess
import sys
from pathlib import Path

import pytest

from host.progress import bar, status, wanted

ROOT = Path(__file__).resolve().parents[2]
EVAL = ["-m", "host", "eval", "--llm", "ground-truth", "--tasks", "1,2", "--trials", "1", "--no-run"]


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_bar_draws_on_a_terminal_and_is_silent_elsewhere(capsys: pytest.CaptureFixture[str]) -> None:
    tty = _Tty()
    with bar("work", 4, fields=("micro",), stream=tty) as b:
        assert b.shown
        b.update(completed=2, micro="0.50")
    drawn = tty.getvalue()
    assert "work" in drawn and "2/4" in drawn and "micro 0.50" in drawn
    pipe = io.StringIO()
    with bar("work", 4, stream=pipe) as b:
        assert not b.shown
        b.update(completed=3, micro="x")
        b.print("a plain line")
    assert pipe.getvalue() == "" and capsys.readouterr().out == "a plain line\n"
    quiet = _Tty()
    with bar("work", 4, quiet=True, stream=quiet) as b, status("booting", quiet=True, stream=quiet):
        assert not b.shown
    assert quiet.getvalue() == "" and not wanted(True, _Tty()) and wanted(False, _Tty())
    spinner = _Tty()
    with status("booting User-Mode Linux", stream=spinner):
        pass
    assert "booting User-Mode Linux" in spinner.getvalue()


def _run(args: list[str], out: Path, *, tty: bool) -> str:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "COLUMNS": "120", "TERM": "xterm"}
    cmd = [sys.executable, *args, "--out", str(out)]
    if not tty:
        return subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=120, check=True).stdout
    leader, follower = pty.openpty()
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdin=subprocess.DEVNULL, stdout=follower, stderr=subprocess.DEVNULL)
    os.close(follower)
    chunks = []
    while True:
        try:
            data = os.read(leader, 65536)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    os.close(leader)
    assert proc.wait(timeout=120) == 0
    return b"".join(chunks).decode(errors="replace")


def test_eval_progress_lines_unchanged_in_a_pipe_a_bar_on_a_terminal(tmp_path: Path) -> None:
    piped = _run(EVAL, tmp_path / "a", tty=False)
    jobs = [re.sub(r", [\d.]+ s \(LLM [\d.]+ s\)$", "", line) for line in piped.splitlines()[:2]]  # minus wall times
    assert jobs == ["[1/2] task 1 trial 0: DSBC 1.00", "[2/2] task 2 trial 0: DSBC 1.00"]
    assert "\x1b[" not in piped  # no terminal control codes in a pipe
    quiet = _run([*EVAL, "--quiet"], tmp_path / "b", tty=False)
    assert not re.search(r"^\[\d+/\d+\]", quiet, re.M) and quiet.startswith("micro 1.00")
    drawn = _run(EVAL, tmp_path / "c", tty=True)
    assert "eval ground-truth" in drawn and "2/2" in drawn and "micro 1.00" in drawn
    assert "[2/2] task 2 trial 0: DSBC 1.00" in drawn  # the per-job lines still print, above the bar
    quiet_tty = _run([*EVAL, "--quiet"], tmp_path / "d", tty=True)
    assert "eval ground-truth" not in quiet_tty and "[1/2]" not in quiet_tty and "micro 1.00" in quiet_tty
