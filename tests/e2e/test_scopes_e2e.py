"""Scopes on the emulated board (issue 19), from telemetry and the board's frame log, in lockstep.

* ``<wait until="any">`` of a 3 s head nod and a 0.5 s ear flap ends ~0.5 s after they start;
  the nod is cancelled: the board gets a FLUSH of the head servos before the cut it names, and
  from that cut on the head's commanded targets no longer move (the board's command stops within
  one control tick, 2 ms at 500 Hz); telemetry shows the head settling there.
* ``timeout="1"`` on a ~3 s walk (4 strides, 2.8 s) ends the scope 1 s of board time after it
  started (within one telemetry period); the legs stop the same way.
* A skill's calls run under its RUN (``wait[0]/RUN[0]/head_act[0]``) and are cancelled with it.

The whole reply is buffered (``buffer_response``) so the children of a scope are dispatched
together, as an LLM that wrote them in one breath would have them.
"""

from __future__ import annotations

import json

import numpy as np

from firmware_sim.config import BoardConfig
from host.shell.skills import SkillStore
from protocol.framelog import iter_records
from robots.coco import load_poses
from robots.coco import motions as coco_motions
from robots.coco.motions import channel_servos

from .conftest import E2ERun, mask_of, run_e2e

TICK_S = 1.0 / BoardConfig().rate_hz  # 2 ms
REPORT_S = 1.0 / BoardConfig().telemetry_rate_hz  # 20 ms: the board clock the host sees moves in these steps
LOOKAHEAD_S = 0.06  # the streamer's lookahead: a lockstep cut is at the first frame not yet sent


def _board_rx(run: E2ERun, msg_type: str) -> list[dict]:
    with open(run.out / "board_frames.jsonl", encoding="utf-8") as f:
        return [r for r in iter_records(f) if r["dir"] == "rx" and r.get("type") == msg_type]


def check_stopped_at_the_cut(run: E2ERun, channel: str, after: float) -> float:
    """The board's view of cancelling ``channel``'s motion after board time ``after``: the FLUSH of its
    servos arrived no later than the cut it names, and the commanded targets of those servos are
    the same at every frame from the cut on (so the command stops within one tick). Returns the cut (s)."""
    servos = list(channel_servos(channel))
    mask = mask_of(servos)
    flushes = [r for r in _board_rx(run, "FLUSH") if r["fields"]["mask"] == mask and r["fields"]["from_us"] >= after * 1e6]
    assert len(flushes) == 1, flushes
    cut = flushes[0]["fields"]["from_us"] * 1e-6
    assert flushes[0]["t"] <= cut + 1e-9, "the board got the FLUSH after the cut it names"
    assert cut - after <= LOOKAHEAD_S + REPORT_S + 1e-9, (cut, after)
    frames = [(r["fields"]["apply_at_us"] * 1e-6, np.asarray(r["fields"]["targets"])[servos])
              for r in _board_rx(run, "SERVO_FRAME") if r["fields"]["mask"] & mask]
    at_cut = [q for t, q in frames if abs(t - cut) < 1e-9]
    later = [q for t, q in frames if t > cut + 1e-9]
    assert at_cut and later, "no frames for the channel around the cut"
    assert max(float(np.abs(q - at_cut[-1]).max()) for q in later) < 1e-4, "the command moved after the cut"
    # the commanded motion was really moving into the cut (there was something to stop)
    before = [q for t, q in frames if cut - 0.05 <= t < cut - 1e-9]
    assert before and float(np.abs(before[0] - at_cut[-1]).max()) > np.radians(0.5)
    # telemetry: the servos settle where the cut left them
    t, q, v = run.telemetry
    tail = t >= cut + 0.15
    assert tail.sum() >= 5
    assert np.degrees(np.ptp(q[tail][:, servos], axis=0)).max() < 1.0
    assert np.degrees(np.abs(q[tail][:, servos] - at_cut[-1]).max()) < 2.0
    return cut


def test_wait_until_any_ends_with_the_ear_flap_and_stops_the_nod(tmp_path) -> None:
    run = run_e2e('<wait until="any"><head_act action="nod" duration="3"/><shake_ear duration="0.5"/></wait>',
                  tmp_path, buffer_response=True, plots=True)
    scope, nod, ear = run.one("wait"), run.one("head_act"), run.one("shake_ear")
    assert (scope.outcome, scope.ended_by, scope.args) == ("done", "wait[0]/shake_ear[0]", {"until": "any"}), run.table()
    assert ear.outcome == "done" and nod.outcome == "cancelled", run.table()
    assert abs(nod.start - ear.start) <= 0.02  # dispatched together
    assert abs((ear.end - ear.start) - 0.5) <= 0.03
    assert 0.45 <= scope.end - ear.start <= 0.5 + 0.03 + REPORT_S, run.table()  # ~0.5 s
    assert ear.end - 1e-9 <= scope.end <= ear.end + REPORT_S + 1e-9  # ended as the host saw the flap end
    cut = check_stopped_at_the_cut(run, "head", after=scope.end)
    assert nod.start < scope.end and nod.end <= cut + 0.1
    doc = json.loads((tmp_path / "timeline.json").read_text())
    assert [(c["path"], c["outcome"]) for c in doc["calls"]] == [
        ("wait[0]", "done"), ("wait[0]/head_act[0]", "cancelled"), ("wait[0]/shake_ear[0]", "done")]
    assert doc["calls"][0]["ended_by"] == "wait[0]/shake_ear[0]" and "ended_by" not in doc["calls"][1]
    assert (tmp_path / "timeline.png").stat().st_size > 0


def test_timeout_ends_a_walk_at_one_second_of_board_time(tmp_path) -> None:
    stand = np.asarray(load_poses()["stand"], dtype=float)
    assert coco_motions.BEHAVIOURS["move_strides"](stand, times=4, direction="forward").t[-1] >= 2.5
    run = run_e2e('<wait timeout="1"><move_forward times="4"/></wait>Done.', tmp_path, buffer_response=True)
    scope, walk, said = run.one("wait"), run.one("move_forward"), run.one("speak")
    assert (scope.outcome, scope.ended_by, scope.args) == ("timeout", "timeout", {"timeout": 1.0}), run.table()
    assert abs((scope.end - scope.start) - 1.0) <= REPORT_S + 1e-6, run.table()
    assert walk.outcome == "cancelled" and walk.start < scope.end
    check_stopped_at_the_cut(run, "body", after=scope.end)
    assert said.start >= walk.end - 1e-9  # what follows the scope waits for the stopped walk
    assert run.report.summary.outcome == "done" and run.report.summary.outcomes["timeout"] == 1
    assert not run.report.summary.fell


def test_a_runs_calls_are_under_it_and_cancelled_with_it(tmp_path) -> None:
    skills = SkillStore()
    skills.save("nodding", "nod for a while", '<head_act action="nod" duration="3"/>')
    run = run_e2e('<wait until="any"><RUN id="nodding"/><shake_ear duration="0.5"/></wait>', tmp_path,
                  buffer_response=True, skills=skills)
    doc = json.loads((tmp_path / "timeline.json").read_text())
    assert [(c["path"], c["outcome"]) for c in doc["calls"]] == [
        ("wait[0]", "done"), ("wait[0]/RUN[0]", "cancelled"), ("wait[0]/RUN[0]/head_act[0]", "cancelled"),
        ("wait[0]/shake_ear[0]", "done")], run.table()
    nod, run_el = run.one("head_act"), run.one("RUN")
    assert nod.start is not None and run_el.start <= nod.start and run_el.end >= run.one("wait").end
    check_stopped_at_the_cut(run, "head", after=run.one("wait").end)
