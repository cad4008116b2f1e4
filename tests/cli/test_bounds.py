"""Bounds a user can see and set (issue 16, item 2), on real runs.

The issue's inputs: 2 MB of prose (``run --xml-file``: refused before anything runs, in
``test_exit_codes.py``; streamed by a model: stopped at the default board-time bound in seconds of
wall time) and 20 000 calls (refused before anything runs, ``test_exit_codes.py``). A run stopped
at a bound ends like an interrupted one (rest pose, artefacts), with outcome ``limit``, the reason
in ``summary.json``, one line, exit status 1.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from host.run.stops import DEFAULT_MAX_BOARD_S
from support.fake_llm import FakeLLM, Handler, chunk, fake_llm, sse  # noqa: F401  (fixture)

pytestmark = pytest.mark.timeout(300)

PROSE = "All work and no play makes the robot a dull robot. " * 40_000  # the 2 MB of prose


def _ghostshell(*args: str, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host", *args], capture_output=True, text=True, timeout=timeout,
                          stdin=subprocess.DEVNULL)


def _check_stopped(r: subprocess.CompletedProcess[str], out: Path, by: str, says: str) -> dict:
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 1, r.stderr[-3000:]
    assert len(err) == 1 and says in err[0] and "rest pose 'stand'" in err[0], err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "limit", summary
    assert summary["extra"]["stopped"]["by"] == by and says in summary["extra"]["stopped"]["message"]
    assert summary["extra"]["stopped"]["rest_pose"] == "stand"
    assert (out / "timeline.json").exists() and (out / "joints.png").exists()
    return summary


def test_two_megabytes_of_streamed_prose_stop_at_the_default_board_time_bound(fake_llm: FakeLLM,  # noqa: F811
                                                                              tmp_path: Path) -> None:
    def respond(h: Handler, fake: FakeLLM) -> None:
        h.start_sse()
        h.write_piece(sse(chunk("", role="assistant")))
        for i in range(0, len(PROSE), 4096):
            if not h.write_piece(sse(chunk(PROSE[i:i + 4096]))):
                return  # the run cut the stream
        h.write_piece(sse(chunk(None, finish="stop")))
        h.write_piece(b"data: [DONE]\n\n")
        h.end_chunked()

    fake_llm.responder = respond
    out = tmp_path / "run"
    t0 = time.monotonic()
    r = _ghostshell("run", "--prompt", "Tell me everything.", "--llm", "openai:test-model", "--base-url",
                    fake_llm.base_url, "--api-key", "test-key", "--lockstep", "--no-live", "--out", str(out))
    wall = time.monotonic() - t0
    summary = _check_stopped(r, out, "max_board_s", f"board-time bound of {DEFAULT_MAX_BOARD_S:g} s")
    assert DEFAULT_MAX_BOARD_S <= summary["duration_s"] < DEFAULT_MAX_BOARD_S + 5, summary["duration_s"]
    # bounded output too: far from the 452 MB of logs
    logs = sum(p.stat().st_size for p in out.glob("*_frames.*"))
    assert logs < 100e6, logs
    print(f"2 MB streamed prose stopped at {summary['duration_s']} board s after {wall:.1f} s wall; logs {logs / 1e6:.1f} MB")


def test_a_board_time_bound_set_by_the_user(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = _ghostshell("run", "--xml", '<head_act action="nod" duration="30"/>', "--lockstep", "--no-live",
                    "--max-board-s", "2", "--out", str(out))
    summary = _check_stopped(r, out, "max_board_s", "board-time bound of 2 s")
    calls = json.loads((out / "timeline.json").read_text())["calls"]
    assert [c["outcome"] for c in calls] == ["interrupted"], calls
    assert 2.0 <= summary["duration_s"] < 4.0


def test_a_log_size_bound(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = _ghostshell("run", "--task", "9", "--lockstep", "--no-live", "--max-log-mb", "0.5", "--out", str(out))
    _check_stopped(r, out, "max_log_mb", "over the bound of 0.5 MB")
    # the bound is checked every 0.25 s of wall time, so the logs end a little past it, not far
    logs = sum(p.stat().st_size for p in out.glob("*_frames.*"))
    assert 0.5e6 < logs < 5e6, logs
