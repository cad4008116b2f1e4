"""Standard output that cannot be written never stops a command (:mod:`host.commands.stdout_guard`).

Found by a reviewer (2026-12-08): ``ghostshell run ... | head -1`` exited 1 with a 64-line
BrokenPipeError traceback, and ``run ... > /dev/full`` never wrote summary.json and timeline.json
(eval never wrote eval.json; prompt, dsbc, dbc gave tracebacks). Now a reader that left drops the rest
of the output silently with the command's own status; any other write error is one line at the end and
status 1; the run's artefacts are written either way. Also ``render --out x.txt`` (ffmpeg has no container
for it) is refused when the arguments are read, exit 2, not after rendering with ffmpeg's report.

Real processes (``python -m host``; a lockstep run of task 26 takes about a second): stdout is a pipe
whose reader is gone before the command starts (EPIPE on the first write, whatever the load), a pipe
closed after its first line (the banner; the rest comes after the turn), and ``/dev/full`` (ENOSPC).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]
RUN = ["run", "--task", "26", "--lockstep", "--no-plots", "--no-live"]
FULL = "could not write to stdout: No space left on device"


def _start(args: list[str], stdout: int, stderr: Path) -> subprocess.Popen[bytes]:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    with stderr.open("wb") as err:
        return subprocess.Popen([sys.executable, "-m", "host", *args], cwd=ROOT, env=env,
                                stdin=subprocess.DEVNULL, stdout=stdout, stderr=err)


def _with_reader_gone(args: list[str], stderr: Path) -> int:
    """Run the command with stdout a pipe that has no reader (every write is EPIPE); its exit status."""
    r, w = os.pipe()
    os.close(r)
    try:
        proc = _start(args, w, stderr)
    finally:
        os.close(w)
    return proc.wait(timeout=100)


def _with_dev_full(args: list[str], stderr: Path) -> int:
    with open("/dev/full", "wb") as full:
        proc = _start(args, full.fileno(), stderr)
    return proc.wait(timeout=100)


def _artefacts_written(out: Path) -> None:
    assert (out / "summary.json").is_file() and (out / "timeline.json").is_file()


def test_run_whose_reader_is_gone_runs_on_silently(tmp_path: Path) -> None:
    out = tmp_path / "run"
    status = _with_reader_gone([*RUN, "--out", str(out)], tmp_path / "err")
    assert (tmp_path / "err").read_text() == ""
    assert status == 0
    _artefacts_written(out)


def test_run_piped_to_a_reader_that_leaves_after_one_line(tmp_path: Path) -> None:
    """As ``| head -1``: the banner is read, then the pipe closes while the turn runs."""
    out = tmp_path / "run"
    proc = _start([*RUN, "--out", str(out)], subprocess.PIPE, tmp_path / "err")
    assert proc.stdout is not None
    first = proc.stdout.readline()
    proc.stdout.close()
    status = proc.wait(timeout=100)
    assert first.startswith(b"task 26")
    assert (tmp_path / "err").read_text() == ""
    assert status == 0
    _artefacts_written(out)


def test_run_to_a_full_device_writes_its_artefacts_and_says_so_once(tmp_path: Path) -> None:
    out = tmp_path / "run"
    status = _with_dev_full([*RUN, "--out", str(out)], tmp_path / "err")
    assert (tmp_path / "err").read_text().splitlines() == [f"ghostshell run: {FULL}"]
    assert status == 1
    _artefacts_written(out)


@pytest.mark.parametrize("args", [["prompt"], ["dbc"], ["--help"]], ids=["prompt", "dbc", "help"])
def test_short_output_to_a_gone_reader_or_a_full_device(tmp_path: Path, args: list[str]) -> None:
    """Output small enough to stay in the buffer fails only at the last flush: still one line, or none."""
    assert _with_reader_gone(args, tmp_path / "pipe") == 0
    assert (tmp_path / "pipe").read_text() == ""
    assert _with_dev_full(args, tmp_path / "full") == 1
    who = f"ghostshell {args[0]}" if not args[0].startswith("-") else "ghostshell"
    assert (tmp_path / "full").read_text().splitlines() == [f"{who}: {FULL}"]


@pytest.mark.parametrize("name", ["x.txt", "timeline.json", "dangling"])
def test_render_refuses_a_file_no_video_can_be_written_as(tmp_path: Path, name: str) -> None:
    (tmp_path / "timeline.json").write_text("{}")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    proc = subprocess.run([sys.executable, "-m", "host", "render", str(tmp_path), "--out", str(tmp_path / name)],
                          cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stdout == ""
    (line,) = proc.stderr.splitlines()
    assert line.startswith("ghostshell render: error: argument --out:") and ".mp4" in line and ".mkv" in line
