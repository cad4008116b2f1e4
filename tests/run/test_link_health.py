"""The line ``ghostshell run`` ends with when the link had trouble (``host.run.link_health``).

A realtime run over ``--faults 'delay=200±50'`` ended "task 23: done", exit 0, with nothing else in
the terminal, while its summary.json counted 17 board watchdog trips and 18 re-sent requests. The
extras below are that summary's shape (summary.json's ``extra``)."""

from __future__ import annotations

from pathlib import Path

from host.run.link_health import MAX_BOARD_WARNINGS, board_warnings, link_health_line

CLEAN = {"frames_sent": 362, "frames_skipped": 0, "late": 0, "dropped": 0, "frame_nacks": 0,
         "decode_errors": 0, "retries": 0, "seq_gaps": 0}


def test_a_clean_link_adds_no_line() -> None:
    assert link_health_line({"link": CLEAN}) is None
    assert link_health_line({"link": {}}) is None  # a run the link ended before the runtime existed
    assert link_health_line({}) is None


def test_what_the_link_went_through_is_one_line_with_the_injected_faults() -> None:
    extra = {"link": {**CLEAN, "late": 1, "frame_nacks": 1, "retries": 18},
             "faults": {"host_detected": {}, "board": {"spec": "delay=200±50", "board_detected": {
                 "link_errors": 0, "late_frames": 1, "dropped_frames": 0, "watchdog_trips": 17, "seq_gaps": 2}}}}
    assert link_health_line(extra) == (
        "link: 17 board watchdog trips (servos held), 1 servo frame refused (NACK), 18 requests re-sent, "
        "2 sequence gaps at the board; faults injected: delay=200±50 (counts in summary.json)")


def test_the_boards_counters_since_it_started_are_not_this_runs() -> None:
    """``late``/``dropped`` come from the board's reports and count since it started (a board you started
    yourself keeps earlier runs' refusals): only this session's NACKs are counted."""
    assert link_health_line({"link": {**CLEAN, "late": 40, "dropped": 3}}) is None


def test_counts_a_board_did_not_report_are_left_out() -> None:
    """A board that stopped before printing its fault report leaves ``faults.board`` None; a run that
    never got a report leaves the board's counters None."""
    extra = {"link": {**CLEAN, "frame_nacks": None, "decode_errors": 3},
             "faults": {"host_detected": {}, "board": None}}
    assert link_health_line(extra) == "link: 3 bad frames from the board (counts in summary.json)"


def test_a_watchdog_hold_is_said_without_faults_too() -> None:
    """A host stalled for 0.5 s (``kill -STOP``) on a run without ``--faults``: the board held its servos,
    the run ended "done", and only the reports' WATCHDOG_HOLD edge (``extra.link.watchdog_holds``) knew."""
    assert link_health_line({"link": {**CLEAN, "watchdog_holds": 1}}) == (
        "link: 1 board watchdog trip (servos held) (counts in summary.json)")
    both = {"link": {**CLEAN, "watchdog_holds": 2}, "faults": {"board": {"board_detected": {"watchdog_trips": 3}}}}
    assert link_health_line(both) == "link: 3 board watchdog trips (servos held) (counts in summary.json)"


def test_the_boards_warnings_are_repeated_once_each_and_bounded(tmp_path: Path) -> None:
    stderr = tmp_path / "board.stderr"
    assert board_warnings(stderr) == []  # no file (a board you started yourself)
    slow = "board: warning: telemetry needs ~81500 bit/s, more than 80% of 57600 baud; reports will be dropped, SIM_STATE (the base pose and tilt) first, up to all of them"
    stderr.write_text("board: coco (12 servos), realtime\n" + slow + "\n" + slow + "\n"
                      + "".join(f"board: warning: w{i}\n" for i in range(20)))
    got = board_warnings(stderr)
    assert got[0] == slow and len(got) == MAX_BOARD_WARNINGS and len(set(got)) == len(got)


def test_faults_that_cost_nothing_counted_are_still_said() -> None:
    """``--faults reorder=0.3`` swapped 139 messages and the run ended with no ``link:`` line at all: no
    counter of the host or the board moves when nothing is lost (``late`` counts are not in the line)."""
    injected = [{"direction": "host->board", "units_in": 308, "units_out": 308, "injected": {"drop": 0, "reorder": 70}},
                {"direction": "board->host", "units_in": 308, "units_out": 308, "injected": {"drop": 0, "reorder": 69}}]
    extra = {"link": CLEAN, "faults": {"host_detected": {}, "board": {
        "spec": "reorder=0.3", "injected": injected, "board_detected": {"link_errors": 0, "seq_gaps": 0}}}}
    assert link_health_line(extra) == (
        "link: nothing lost or refused; faults injected: reorder=0.3, 139 message(s) hit (counts in summary.json)")
    none_hit = {"link": CLEAN, "faults": {"board": {"spec": "drop=0.0001", "injected": [
        {"direction": "host->board", "injected": {"drop": 0}}]}}}
    assert link_health_line(none_hit) is None  # nothing injected, nothing seen


def test_the_boards_own_watchdog_holds_are_counted_from_its_stderr(tmp_path: Path) -> None:
    """Two holds in consecutive 50 Hz reports are one rising edge for the host; the board logs both."""
    from host.run.link_health import board_watchdog_holds

    err = tmp_path / "board.stderr"
    assert board_watchdog_holds(err) is None
    err.write_text("board: coco (12 servos), realtime\n"
                   "board: watchdog hold at board time 3.786000 s, 0.202000 s after the last valid message\n"
                   "board: watchdog resume at board time 3.788000 s, a valid message ended the hold after 0.002000 s\n"
                   "board: watchdog hold at board time 3.800000 s, 0.202000 s after the last valid message\n"
                   "board: warning: watchdog hold at the end\n")
    assert board_watchdog_holds(err) == 2
