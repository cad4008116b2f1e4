"""Ctrl-C after the turn, while ``ghostshell run`` writes its artefacts (the plots take a second).

Found while mending a CI failure (2026-12-04): a SIGINT that landed there was lost (status 0, no
word), raised a KeyboardInterrupt that left the plotting thread behind ("interrupted by SIGINT"
and nothing about the artefacts), or killed the process. Now signals stay handled while the
artefacts are written, and the writing always finishes: one signal there says the turn had already
ended (status 130); a second stops the command once the writing is done.

The signals are real (``os.kill`` on this process, handled by the command's AnyIO signal receiver);
they are sent from inside the writer the run hands its thread, so each lands exactly while the
artefacts are being written, whatever the machine's load. The run is a real lockstep one (board
subprocess, pty, MuJoCo), in-process through :func:`host.cli.main` as the console script calls it.
"""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from host.cli import main as cli_main
from host.run.session import RobotSession

pytestmark = pytest.mark.timeout(240)


def _signal_while_writing(monkeypatch: pytest.MonkeyPatch, signals: int) -> list[str]:
    """Make the run's artefact writer send this process ``signals`` SIGINTs first; the returned list
    names what had been written when they were sent."""
    seen: list[str] = []
    done: list[bool] = []
    real = RobotSession.writer

    def writer(self: RobotSession, turn: object, label: str, **kw: object) -> Callable[[], None]:
        write = real(self, turn, label, **kw)  # type: ignore[arg-type]

        def interrupted_write() -> None:
            if done:  # the first writer only (a forced stop writes the JSON files again)
                return write()
            done.append(True)
            seen.extend(sorted(p.name for p in self.out.iterdir()))
            for _ in range(signals):
                handled = self.stop is not None
                os.kill(os.getpid(), signal.SIGINT)
                # two SIGINTs sent together merge into one: the next goes once the loop took this one
                # (the first is recorded as the session's stop; a second sets nothing to wait for)
                deadline = time.monotonic() + 30
                while not handled and self.stop is None and time.monotonic() < deadline:
                    time.sleep(0.001)
            write()

        return interrupted_write

    monkeypatch.setattr(RobotSession, "writer", writer)
    return seen


def _run(tmp_path: Path) -> tuple[int, Path]:
    out = tmp_path / "run"
    return cli_main(["run", "--task", "1", "--lockstep", "--no-live", "--out", str(out)]), out


def test_one_ctrl_c_while_writing_finishes_the_artefacts_and_says_the_turn_had_ended(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    seen = _signal_while_writing(monkeypatch, 1)
    rc, out = _run(tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert "timeline.png" not in seen  # the signal came before the plots were drawn
    assert rc == 130, err
    assert len(err) == 1 and "interrupted by SIGINT (Ctrl-C)" in err[0], err
    assert "the turn had already ended" in err[0] and f"artefacts in {out}/" in err[0], err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "done"  # the turn itself had finished
    for name in ("timeline.json", "timeline.png", "joints.png"):
        assert (out / name).stat().st_size > 0, name


def test_two_ctrl_c_while_writing_stop_once_the_writing_is_done(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _signal_while_writing(monkeypatch, 2)
    rc, out = _run(tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 130, err
    assert len(err) == 1 and "then SIGINT again: stopped at once" in err[0], err
    assert f"summary.json and timeline.json in {out}/" in err[0], err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "interrupted"
    assert summary["extra"]["stopped"]["by"] == "SIGINT" and summary["extra"]["stopped"]["forced_by"] == "SIGINT"
    assert summary["outcomes"]["done"] == 1  # the call itself had finished before the signals
    for name in ("timeline.json", "timeline.png", "joints.png"):  # the writing was not cut
        assert (out / name).stat().st_size > 0, name
