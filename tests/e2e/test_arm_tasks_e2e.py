"""The desk arm's tasks end to end on its emulated board, in lockstep over a real pty.

Each task's ground truth runs once (``run_program(RunOptions(robot="arm", ...))``: board ``python -m
firmware_sim --robot arm --lockstep`` on a pty, the table scene with its two cubes). Checked per task:
every call done and the lifecycle and channel rules (``check_common``, shared with CoCo's tasks);
the order and overlap of the calls on the board clock; gestures counted in the measured joint
angles; and where the cubes ended up.

Where the cubes are: SIM_STATE reports only how many objects the scene has; the emulated board also
writes its objects' poses with every SIM_STATE to ``objects.jsonl`` (``--objects-log``, simulation
ground truth, never on the link), and its last line is where the cubes ended up. Cross-checked once
(task 5) against an in-process lockstep board that receives the run's host traffic again
(:func:`support.board_replay.replay_in_process`), whose TELEMETRY equals what the run's board sent.

The suite runs :data:`REPRESENTATIVE` tasks (a pick and place, speech in parallel with a gesture, a
scoped termination; the demo task 12 and eval's tasks run in test_arm_cli_e2e.py) so it stays fast;
``GHOSTSHELL_ALL_TASKS=1`` runs every task here and in the link and fault tests, each with its check.
"""

from __future__ import annotations

import itertools
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from e2e.task_checks import before, check_common, count_swings, follows, lasts, overlap, together
from robots.arm.behaviours import geometry, places
from robots.registry import load_robot
from support.board_replay import replay_in_process

from .conftest import FRAME_S, PROMPT_S, SPEECH_PROMPT_S, E2ERun, mask_of, run_e2e

ARM = load_robot("arm")
TASKS = {i: t for i, t in ARM.tasks.items() if t.ground_truth}
PAN, LIFT, ELBOW, WFLEX, WROLL, GRIP = range(6)
CUBE = 0.0125  # half size (m)
_RUNS: dict[int, E2ERun] = {}
#: every task's check runs with GHOSTSHELL_ALL_TASKS=1; by default only these (CI time)
ALL_TASKS = os.environ.get("GHOSTSHELL_ALL_TASKS", "") not in ("", "0")
REPRESENTATIVE = (5, 8, 13)


def selected(*tids: int) -> list[int]:
    """The task ids a parametrized test runs: ``tids`` (a representative few), or all with ground truth
    when ``GHOSTSHELL_ALL_TASKS`` is set."""
    return sorted(TASKS) if ALL_TASKS else sorted(tids)


@pytest.fixture(scope="session")
def arm_run(tmp_path_factory: pytest.TempPathFactory):
    """``arm_run(tid) -> E2ERun``: the arm's task ``tid`` run once per session."""
    def get(tid: int) -> E2ERun:
        if tid not in _RUNS:
            out = tmp_path_factory.mktemp(f"arm_task{tid}")
            _RUNS[tid] = run_e2e(TASKS[tid].ground_truth, out, robot="arm", task_label=f"arm task {tid}")
        return _RUNS[tid]
    return get


def start_of(name: str) -> np.ndarray:
    return np.asarray(ARM.scene().object(name).pos)


def final_objects(out: Path) -> dict[str, np.ndarray]:
    """Where the scene's objects are at the end of the run in ``out`` (its board's objects log, the
    last record: positions in m)."""
    lines = (out / "objects.jsonl").read_text(encoding="utf-8").splitlines()
    assert len(lines) > 10, "the board wrote no objects log"
    return {k: np.asarray(v[:3]) for k, v in json.loads(lines[-1])["objects"].items()}


def cubes_after(run: E2ERun) -> dict[str, np.ndarray]:
    return final_objects(run.out)


def swings(run: E2ERun, servo: int, start: float, end: float, *, below: bool, depth_deg: float) -> int:
    t, q, _ = run.telemetry
    return count_swings(q[(t >= start) & (t <= end + 0.3), servo], below=below, depth_deg=depth_deg)


def grasp_at(run: E2ERun, t_s: float) -> np.ndarray:
    """The grasp point (m, forward kinematics of the measured joint angles) at board time ``t_s``."""
    t, q, _ = run.telemetry
    i = max(int(np.searchsorted(t, t_s, side="right")) - 1, 0)
    return geometry().forward(q[i])[0]


def on_top(cubes: dict[str, np.ndarray], upper: str, lower: str) -> None:
    up, low = cubes[upper], cubes[lower]
    assert abs(up[2] - (low[2] + 2 * CUBE)) < 0.003, f"{upper} at z {up[2]:.4f}, not on {lower} ({low[2]:.4f})"
    assert np.linalg.norm(up[:2] - low[:2]) < 0.008, f"{upper} is {np.linalg.norm(up[:2] - low[:2]) * 1000:.1f} mm off"


def unmoved(cubes: dict[str, np.ndarray], name: str) -> None:
    assert np.linalg.norm(cubes[name] - start_of(name)) < 0.004, f"{name} moved to {cubes[name]}"


#: the tasks that move a cube, and where it must end up
MOVES = {2: "lifted", 5: "stacked", 7: "left", 12: "stacked", 14: "front"}


def check_cubes(tid: int, cubes: dict[str, np.ndarray]) -> None:
    """Where the cubes are after task ``tid`` (world positions, m): moved as the task says, the other one not."""
    what = MOVES.get(tid)
    if what is None:
        for name in cubes:
            unmoved(cubes, name)
    elif what == "lifted":
        red = cubes["red_cube"]
        assert red[2] > start_of("red_cube")[2] + 0.05, f"the red cube was not lifted: z {red[2]:.3f}"
        assert np.linalg.norm(red[:2] - start_of("red_cube")[:2]) < 0.01
        unmoved(cubes, "blue_cube")
    elif what == "stacked":
        on_top(cubes, "red_cube", "blue_cube")
        unmoved(cubes, "blue_cube")
    else:
        spot = np.asarray(places()[what])
        blue = cubes["blue_cube"]
        assert np.linalg.norm(blue[:2] - spot) < 0.01 and abs(blue[2] - CUBE) < 0.003, f"the blue cube is at {blue}"
        unmoved(cubes, "red_cube")


def check_task(tid: int, run: E2ERun) -> None:
    f, one = run.find, run.one
    if tid == 1:
        w = one("wave")
        assert w.channel == "arm" and len(run.calls) == 1
        assert swings(run, PAN, w.start, w.end, below=False, depth_deg=10) == 1  # one wave = one swing each way
        assert swings(run, PAN, w.start, w.end, below=True, depth_deg=10) == 1
    elif tid == 2:
        p = one("pick", object="red_cube")
        cubes = cubes_after(run)
        check_cubes(tid, cubes)
        assert np.linalg.norm(grasp_at(run, p.end + 0.3) - cubes["red_cube"]) < 0.01  # it is in the gripper
    elif tid == 3:
        n = one("nod")
        assert 0.4 <= n.end - n.start <= 1.2
        assert swings(run, WFLEX, n.start, n.end, below=False, depth_deg=10) == 1
    elif tid == 4:
        sp, w = one("speak", text="Hello, I am a desk arm"), one("wave", times=2)
        follows(sp, w)
        assert swings(run, PAN, w.start, w.end, below=False, depth_deg=10) == 2
    elif tid in (5, 12):
        pick, place = one("pick", object="red_cube"), one("place", object="red_cube", on="blue_cube")
        if tid == 5:
            follows(pick, place, within=FRAME_S + 1e-9)  # one channel, queued: they flow into each other
            # the objects log against an in-process replay of the host's traffic (the same physics)
            rep = replay_in_process(run.out, "arm")
            err, n = rep.max_telemetry_error(run.out)
            assert n > 50 and err < 1e-4, f"the replay is not the run's physics ({n} reports, {err} rad)"
            logged = cubes_after(run)
            for name, pos in rep.objects().items():
                assert np.linalg.norm(np.asarray(pos) - logged[name]) < 0.001, (name, pos, logged[name])
        else:
            talk, done = one("speak", text="I am picking up the red cube."), f("speak")[-1]
            overlap(pick, talk)  # it talks while it picks
            follows(pick, place)
            follows(place, done, within=SPEECH_PROMPT_S)
        check_cubes(tid, cubes_after(run))
    elif tid == 6:
        pb, pr, nod = one("point_at", target="blue_cube"), one("point_at", target="red_cube"), one("nod")
        for a, b in itertools.pairwise((pb, pr, nod)):
            follows(a, b, within=FRAME_S + 1e-9)
        for c, cube in ((pb, "blue_cube"), (pr, "red_cube")):
            g = grasp_at(run, c.end + 0.05)
            assert np.linalg.norm(g[:2] - start_of(cube)[:2]) < 0.01, f"pointing {g} is not above {cube}"
    elif tid == 7:
        pick, place, done = one("pick", object="blue_cube"), one("place", on="left"), one("speak", text="Done")
        follows(pick, place)
        follows(place, done, within=SPEECH_PROMPT_S)
        check_cubes(tid, cubes_after(run))
    elif tid == 8:
        sn, sp = one("snap", times=3), one("speak")
        overlap(sn, sp)
        together(sn, sp, within=SPEECH_PROMPT_S)
        assert swings(run, GRIP, sn.start, sn.end, below=False, depth_deg=20) == 3
    elif tid == 9:
        nod, rel = one("nod"), one("release")
        together(nod, rel, within=0.1)
        overlap(nod, rel)
        t, q, _ = run.telemetry
        assert math.degrees(q[t >= rel.end + 0.2][0, GRIP]) > 40  # the gripper opened
    elif tid == 10:
        sh, bgm = one("shake", duration=3.0), one("play_bgm", duration=3.0)
        lasts(sh, 3.0, tol=0.25)  # whole shakes, and the return to where it began
        lasts(bgm, 3.0)
        together(sh, bgm, within=0.25)
        assert swings(run, WROLL, sh.start, sh.end, below=False, depth_deg=12) >= 3
    elif tid == 11:
        bgm, wave, pt, cap = one("play_bgm"), one("wave"), one("point_at", target="red_cube"), one("capture")
        overlap(bgm, wave)
        before(wave, pt)
        follows(bgm, pt)
        follows(pt, cap)
        assert run.report.summary.extra["captures"], "no image came back from the wrist camera"
    elif tid == 13:
        sn, nod = one("snap"), one("nod", times=3)
        assert sn.persistent and not nod.persistent and sn.start <= nod.start
        assert 0 <= sn.end - nod.end <= 0.3, f"snapping stopped {sn.end - nod.end:.3f} s after the nods"
        arm_gripper = mask_of([GRIP])
        cuts = [x["from_us"] * 1e-6 for x in run.host_sent("FLUSH") if x["mask"] == arm_gripper]
        assert len(cuts) == 1 and 0 <= cuts[0] - nod.end <= PROMPT_S, (cuts, nod.end)
        assert swings(run, WFLEX, nod.start, nod.end, below=False, depth_deg=10) == 3
        assert swings(run, GRIP, sn.start, nod.end, below=False, depth_deg=20) >= 2
    elif tid == 14:
        bgm, pick, place = one("play_bgm"), one("pick", object="blue_cube"), one("place", on="front")
        assert bgm.persistent and bgm.start <= pick.start
        follows(pick, place, within=FRAME_S + 1e-9)
        assert 0 <= bgm.end - place.end <= 0.3
        check_cubes(tid, cubes_after(run))
    elif tid == 15:
        wave, sp = one("wave"), one("speak", text="Goodbye, see you soon")
        assert wave.persistent and wave.start <= sp.start
        arm = mask_of(ARM.channels["arm"].servos)
        cuts = [x["from_us"] * 1e-6 for x in run.host_sent("FLUSH") if x["mask"] == arm]
        assert len(cuts) == 1 and 0 <= cuts[0] - sp.end <= PROMPT_S, (cuts, sp.end)
        assert 0 <= wave.end - sp.end <= 1.2  # the raised hand's smooth return home
        assert swings(run, PAN, wave.start, sp.end, below=False, depth_deg=10) >= 1
    else:  # pragma: no cover
        raise AssertionError(f"no check for arm task {tid}")


@pytest.mark.parametrize("tid", selected(*REPRESENTATIVE))
def test_arm_task_end_to_end(tid: int, arm_run) -> None:
    run = arm_run(tid)
    check_common(run)
    s = run.report.summary
    assert s.extra["robot"] == "arm" and s.extra["scene"] == {"name": "table", "objects": 2, "toppled": 0}
    assert not s.fell and s.base_start == s.base_end == [0.0, 0.0, 0.0]  # bolted to the table
    check_task(tid, run)
    check_cubes(tid, cubes_after(run))


def test_every_task_has_a_check() -> None:
    assert sorted(TASKS) == list(range(1, 16))
