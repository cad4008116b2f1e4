"""The "could not keep up" decision of a realtime run (host/run/realtime_health.py): counts in, one line or None."""

from __future__ import annotations

import json
from pathlib import Path

from host.run.realtime_health import (
    LATENESS_PREFIX, add_realtime_behind, board_lateness, realtime_behind, realtime_behind_line,
)

#: what the C firmware's board printed after a run whose plant was stopped for half a second
BEHIND = {"bus_late_replies": 134, "bus_stalls": 162, "board_ticks_skipped": 151, "board_overruns": 180,
          "late_frames": 0, "bus_silent_max_ms": 634, "plant_late_steps": 55, "plant_behind_max_ms": 633,
          "plant_steps_skipped": 315, "plant_resyncs": 2}
QUIET = {"bus_late_replies": 2, "bus_stalls": 0, "board_ticks_skipped": 0, "board_overruns": 4, "late_frames": 0,
         "bus_silent_max_ms": 12, "plant_late_steps": 1, "plant_behind_max_ms": 9, "plant_steps_skipped": 0,
         "plant_resyncs": 0}


def test_a_run_that_kept_up_says_nothing() -> None:
    assert realtime_behind({"frames_sent": 400, "late": 2}, QUIET) is None  # 2 late: under LATE_MIN
    assert realtime_behind({"frames_sent": 400, "late": None}, None) is None  # the Python board: no record
    assert realtime_behind_line(None) is None


def test_lockstep_is_never_behind() -> None:
    assert realtime_behind({"frames_sent": 10, "late": 10}, BEHIND, clock="lockstep") is None


def test_a_stalled_plant_is_one_line_that_suggests_lockstep() -> None:
    behind = realtime_behind({"frames_sent": 410, "late": 0}, BEHIND)
    assert behind is not None
    assert behind["suggest"] == "--lockstep" and behind["bus_silent_max_ms"] == 634
    assert [r.split(" ")[1] for r in behind["reasons"]] == ["board", "servo", "plant"]
    line = realtime_behind_line(behind)
    assert line is not None and "\n" not in line
    assert "up to 634 ms" in line and "0.30 s of ticks" in line and "--lockstep" in line
    json.dumps(behind)  # it goes into summary.json as is


def test_late_frames_count_against_the_frames_sent() -> None:
    behind = realtime_behind({"frames_sent": 400, "late": 37}, QUIET)
    assert behind is not None and behind["reasons"] == ["37 of 400 frames reached the board late"]
    assert realtime_behind({"frames_sent": 4000, "late": 37}, QUIET) is None  # under 2 %


def test_the_board_record_is_read_from_its_stderr(tmp_path: Path) -> None:
    err = tmp_path / "board.stderr"
    assert board_lateness(err) is None  # no file
    err.write_text("board: coco (12 servos), realtime\n" + LATENESS_PREFIX + json.dumps(BEHIND) + "\n")
    assert board_lateness(err) == BEHIND
    err.write_text(LATENESS_PREFIX + "{not json\n")
    assert board_lateness(err) is None


def test_added_to_a_summary_extra_once_the_board_stopped(tmp_path: Path) -> None:
    err = tmp_path / "board.stderr"
    err.write_text(LATENESS_PREFIX + json.dumps(QUIET) + "\n")
    extra: dict = {"clock": "realtime", "link": {"frames_sent": 400, "late": 0}}
    assert add_realtime_behind(extra, err) is None and "realtime_behind" not in extra
    err.write_text(LATENESS_PREFIX + json.dumps(BEHIND) + "\n")
    line = add_realtime_behind(extra, err)
    assert line is not None and line.startswith("realtime: ") and extra["realtime_behind"]["bus_stalls"] == 162
    assert add_realtime_behind({"clock": "lockstep", "link": {}}, err) is None
