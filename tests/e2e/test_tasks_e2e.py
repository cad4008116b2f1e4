"""All 30 ground-truth programs of the paper end to end on the emulated CoCo, in lockstep over a real pty.

Times are the board's, measured from telemetry (a motion call starts with its
first applied frame and ends with its last; peripherals start/end on the board
clock). Where the virtual-clock shell tests (tests/shell/test_tasks.py) had
exact equalities, these allow a frame period or two (``SAME_S``); a call that a
previous one releases starts on the 10 ms frame grid after the streamer's
lookahead, so "b follows a" means ``a.end <= b.start <= a.end + PROMPT_S``; calls on one
motion channel flow into each other (Task 26: no gap beyond a frame period).
Task 23's "stops within 0.2 s" is measured at the END of the nod's smooth
return (its last applied frame), the strictest reading; the cut itself (the
FLUSH of the head servos in the host's frame log) is checked too, within 0.15 s.
"""

from __future__ import annotations

import pytest

from .conftest import TASKS, run_e2e
from .task_checks import check_common, check_task, together


@pytest.mark.parametrize("tid", sorted(TASKS))
def test_ground_truth_end_to_end(tid: int, task_run) -> None:
    """On the Python board (the C firmware's runs: test_tasks_e2e_c.py)."""
    run = task_run(tid, "python")
    check_common(run, "python")
    check_task(tid, run, "python")


def test_parallel_calls_start_together_when_buffered(tmp_path) -> None:
    """Task 15 with the whole response at once: all four calls start within ~50 ms."""
    run = run_e2e(TASKS[15].ground_truth, tmp_path, buffer_response=True)
    check_common(run)
    cs = [run.one("face_emo", emo="happy"), run.one("head_act"), run.one("push_up"), run.one("shake_ear")]
    together(*cs, within=0.05)


def test_run_distance_20_cm(tmp_path) -> None:
    run = run_e2e('<run_distance distance="20"/>', tmp_path)
    check_common(run)
    c = run.one("run_distance")
    moved = run.moved_forward_m(c.start, c.end)
    assert 0.15 <= moved <= 0.25, f"moved {moved * 100:.1f} cm, not 20 cm"


def test_rotate_90_deg(tmp_path) -> None:
    run = run_e2e('<rotate angle="90"/>', tmp_path)
    check_common(run)
    c = run.one("rotate")
    turned = run.turned_deg(c.start, c.end)
    assert 72 <= turned <= 108, f"turned {turned:.1f} deg, not 90"
