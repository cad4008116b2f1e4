"""Ctrl-C after the turn, while ``ghostshell run`` writes its artefacts (the plots take a fraction of a second).

Found while mending a CI failure (2026-12-04): a SIGINT that landed there was lost (status 0, no
word), raised a KeyboardInterrupt that left the plotting thread behind ("interrupted by SIGINT"
and nothing about the artefacts), or killed the process. Now one guard handles signals over the
session and the writing of its artefacts, and the writing always finishes: a signal there exits 130
and says the turn had already ended; a second one waits for the writing too; one after a bound
stopped the turn makes the status 130, not the bound's 1.

The signals are real (``os.kill`` on this process, handled by the command's AnyIO signal receiver);
they are sent from inside the writer the run hands its worker thread, each once the command has
taken the one before (:class:`host.run.stops.StopSignals` records it), so each lands while the
artefacts are being written, whatever the machine's load. The run is a real lockstep one (board
subprocess, pty, MuJoCo), in-process through :func:`host.cli.main`.
"""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from host.cli import main as cli_main
from host.run import runner
from host.run.robot_session import RobotSession
from host.run.stops import StopSignals

pytestmark = pytest.mark.timeout(240)


def _signal_while_writing(monkeypatch: pytest.MonkeyPatch, signals: int) -> None:
    """The run's first artefact writer sends this process ``signals`` SIGINTs, each once the command's
    :class:`StopSignals` has taken the one before, then writes."""
    taken: list[StopSignals] = []

    class Recorded(StopSignals):
        def __init__(self, *a: Any, **kw: Any) -> None:
            super().__init__(*a, **kw)
            taken.append(self)

    monkeypatch.setattr(runner, "StopSignals", Recorded)
    real = RobotSession.writer
    done: list[bool] = []

    def writer(self: RobotSession, turn: Any, label: str, **kw: Any) -> Callable[[], None]:
        write = real(self, turn, label, **kw)

        def interrupted_write() -> None:
            if not done:  # the first writer only
                done.append(True)
                (stops,) = taken
                for k in range(signals):
                    seen = (lambda: stops.first is not None) if k == 0 else (lambda: stops.forced is not None)
                    os.kill(os.getpid(), signal.SIGINT)
                    deadline = time.monotonic() + 30
                    while not seen() and time.monotonic() < deadline:  # the loop takes it meanwhile
                        time.sleep(0.001)
                    assert seen(), f"signal {k + 1} was not taken"
            write()

        return interrupted_write

    monkeypatch.setattr(RobotSession, "writer", writer)


def _artefacts_whole(out: Path) -> dict[str, Any]:
    for name in ("timeline.png", "joints.png"):
        data = (out / name).read_bytes()
        assert data.startswith(b"\x89PNG") and data.endswith(b"IEND\xaeB`\x82"), name  # a whole PNG
    json.loads((out / "timeline.json").read_text())
    return json.loads((out / "summary.json").read_text())


def _run(tmp_path: Path, *extra: str) -> tuple[int, Path]:
    out = tmp_path / "run"
    return cli_main(["run", "--task", "1", "--lockstep", "--no-live", "--out", str(out), *extra]), out


def test_one_ctrl_c_while_writing_finishes_the_artefacts_and_says_the_turn_had_ended(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _signal_while_writing(monkeypatch, 1)
    rc, out = _run(tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 130, err
    assert len(err) == 1 and "interrupted by SIGINT (Ctrl-C)" in err[0], err
    assert "the turn had already ended" in err[0] and f"artefacts in {out}/" in err[0], err
    assert _artefacts_whole(out)["outcome"] == "done"  # the turn itself had finished


def test_two_ctrl_c_while_writing_still_finish_the_artefacts(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _signal_while_writing(monkeypatch, 2)
    rc, out = _run(tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 130, err
    assert len(err) == 1 and "the turn had already ended" in err[0] and f"artefacts in {out}/" in err[0], err
    assert _artefacts_whole(out)["outcome"] == "done"


def test_a_ctrl_c_after_a_bound_cut_the_turn_is_an_interruption(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _signal_while_writing(monkeypatch, 1)
    rc, out = _run(tmp_path, "--max-board-s", "0.5")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 130, err  # not the bound's 1: the user interrupted
    assert len(err) == 1 and "interrupted by SIGINT (Ctrl-C)" in err[0], err
    summary = _artefacts_whole(out)
    assert summary["outcome"] == "limit" and summary["extra"]["stopped"]["rest_pose"] == "stand", summary
