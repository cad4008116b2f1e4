"""``run --link``: a run on a board that is already serving a link, and links only the emulated board can create."""

from __future__ import annotations

from pathlib import Path

import anyio
import pytest

from host.link.board_process import start_board
from host.link.errors import LinkError
from host.run.runner import RunOptions, RunReport, run_program
from protocol.linkspec import parse_link_spec

pytestmark = pytest.mark.timeout(120)


def _run_on_own_board(tmp_path: Path, board_clock: str, lockstep: bool) -> RunReport:
    """A one-call run on a board started beforehand (``board_clock``: ``--lockstep`` or ``--realtime``)."""
    board = start_board([board_clock], tmp_path / "board.stderr")
    try:
        opts = RunOptions(program='<face_emo emo="happy"/>', out=tmp_path / "run", lockstep=lockstep, link=board.port)
        return anyio.run(run_program, opts, backend="asyncio")
    finally:
        board.stop()


def test_run_on_a_running_board_given_by_its_link_spec(tmp_path: Path) -> None:
    report = _run_on_own_board(tmp_path, "--lockstep", lockstep=True)
    assert report.summary.outcome == "done"
    assert [c.function for c in report.calls] == ["face_emo"]
    assert (tmp_path / "run" / "host_frames.jsonl").stat().st_size > 0
    assert not (tmp_path / "run" / "board_frames.jsonl").exists()  # the run did not start a board of its own


def test_pty_without_the_emulated_board_is_refused(tmp_path: Path) -> None:
    opts = RunOptions(program="<face_emo emo=\"happy\"/>", out=tmp_path, link=parse_link_spec("pty"),
                      emulate_board=False)
    with pytest.raises(LinkError, match="emulated board creates"):
        anyio.run(run_program, opts, backend="asyncio")


def test_a_run_records_the_clock_of_the_board_it_found(tmp_path: Path) -> None:
    """A board you started keeps its own clock: the summary says what its CAPS said, not the run's flag
    (it said "realtime" for this lockstep board, since the run was not given --lockstep)."""
    report = _run_on_own_board(tmp_path, "--lockstep", lockstep=False)
    assert report.summary.outcome == "done"
    assert report.summary.extra["clock"] == "lockstep"


@pytest.mark.realtime
def test_lockstep_asked_of_a_realtime_board_you_started_is_said(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """``--lockstep`` against a realtime board the run did not start was silently moot."""
    with caplog.at_level("WARNING"):
        report = _run_on_own_board(tmp_path, "--realtime", lockstep=True)
    assert report.summary.outcome == "done"
    assert report.summary.extra["clock"] == "realtime"
    assert any("--lockstep: the board on" in r.getMessage() and "runs in realtime" in r.getMessage()
               for r in caplog.records)
