"""The checks of tests/e2e/test_tasks_e2e.py and test_tasks_e2e_c.py (one paper task's ground truth run
end to end): what every run must show (:func:`check_common`) and what each task's must
(:func:`check_task`). Two test files share them so the suite's workers (``--dist loadfile``) run the
Python board's half and the C firmware's half side by side.

How times are read (the board's, from telemetry) and how close "together" or "follows" must be:
the docstring of tests/e2e/test_tasks_e2e.py.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from host.run.artefacts import BoardCall
from robots.coco.motions import channel_servos

from .conftest import FRAME_S, PROMPT_S, SAME_S, SPEECH_PROMPT_S, E2ERun, mask_of

__all__ = ["before", "check_common", "check_task", "count_swings", "follows", "lasts", "overlap", "together"]


def before(a: BoardCall, b: BoardCall) -> None:
    """a ends no later than b starts."""
    assert a.end is not None and b.start is not None and a.end <= b.start + 1e-9, (a, b)


def follows(a: BoardCall, b: BoardCall, within: float = PROMPT_S) -> None:
    """b starts after a ends, promptly (a released b)."""
    before(a, b)
    assert b.start - a.end <= within, f"{b.function} started {b.start - a.end:.3f} s after {a.function} ended"


def overlap(a: BoardCall, b: BoardCall) -> None:
    assert a.start < b.end and b.start < a.end, (a, b)


def together(*calls: BoardCall, within: float = SAME_S) -> None:
    starts = [c.start for c in calls]
    assert max(starts) - min(starts) <= within, [(c.function, c.start) for c in calls]


def lasts(c: BoardCall, seconds: float, tol: float | None = None) -> None:
    """``c`` lasted ``seconds``: to a frame period or two for screen/sound, to 0.15 s for a rhythmic
    motion (it runs whole cycles within the servo speed limits, e.g. a 3 s ear shake takes 3.1 s)."""
    if tol is None:
        tol = SAME_S if c.channel in ("face", "bgm", "speech", "camera") else 0.15
    assert abs((c.end - c.start) - seconds) <= tol, f"{c.function} lasted {c.end - c.start:.3f} s, not {seconds} s"


def count_swings(x: np.ndarray, *, below: bool, depth_deg: float = 8.0) -> int:
    """Excursions of a measured joint angle more than ``depth_deg`` below (or above) where it started:
    one per nod (pitch dips) or ear flap (the ear lifts); hysteresis at half the depth."""
    d = (x[0] - x) if below else (x - x[0])
    hi, lo = math.radians(depth_deg), math.radians(depth_deg / 2)
    n, out = 0, False
    for v in d:
        if not out and v > hi:
            n, out = n + 1, True
        elif out and v < lo:
            out = False
    return n


def wrap180(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def parent_of(run: E2ERun, c: BoardCall) -> BoardCall | None:
    if "/" not in c.path:
        return None
    ppath = c.path.rsplit("/", 1)[0]
    return next(p for p in run.calls if p.path == ppath)


def no_renderer(run: E2ERun) -> list[BoardCall]:
    """Captures the board refused because it has no renderer (the C firmware: an MCU renders nothing)."""
    return [c for c in run.calls if c.function == "capture" and c.outcome == "failed" and "NO_RENDERER" in (c.error or "")]


def check_common(run: E2ERun, firmware: str = "python", *, late_ok: bool = False) -> None:
    """What every ground-truth run must show, whatever the task (and whichever board firmware). ``late_ok``: frames
    refused LATE or dropped are allowed (a realtime emulator the caller found to have fell behind the wall clock:
    tests/cfirmware/test_stm32f4_tasks.py); every other link count must still be 0."""
    s = run.report.summary
    refused = no_renderer(run) if firmware != "python" else []
    assert run.report.result.error is None, run.report.result.error
    assert s.outcome == ("failed" if refused else "done"), run.table()
    assert all(c.outcome == "done" for c in run.calls if c not in refused), run.table()
    assert not s.fell and s.max_tilt_deg < 30, (s.fell, s.max_tilt_deg)
    link = s.extra["link"]
    late = (link["late"] or 0) + (link["dropped"] or 0)
    # a frame refused LATE or dropped is also a frame NACK: allowed ones explain at most that many NACKs
    assert (late_ok or late == 0) and (link["frame_nacks"] or 0) <= (late if late_ok else 0), link
    assert link["decode_errors"] == 0, link
    for c in run.calls:
        if c in refused:
            continue
        assert c.start is not None and c.end is not None and c.start >= run.t0 and c.end >= c.start, c
        # lifecycle: a parent (persistent, or a wait) starts before its children and ends after all of them
        p = parent_of(run, c)
        if p is not None:
            assert p.start <= c.start + 1e-9 and p.end >= c.end - 1e-9, (p, c)
    # a device channel runs one call at a time (a call may only nest inside another on a different channel)
    by_channel: dict[str, list[BoardCall]] = {}
    for c in run.calls:
        if c.channel not in (None, "main"):
            by_channel.setdefault(c.channel, []).append(c)
    for cs in by_channel.values():
        cs.sort(key=lambda c: c.start)
        for a, b in itertools.pairwise(cs):
            before(a, b)


def check_task(tid: int, run: E2ERun, firmware: str = "python") -> None:
    f, one = run.find, run.one
    if tid in (1, 2, 3):
        assert len(run.calls) == 1
        c = run.calls[0]
        assert c.channel == {1: "face", 2: "body", 3: "head"}[tid]
        if tid == 1:  # default 2 s
            lasts(c, 2.0)
        if tid == 3:  # one call = one gesture: a single nod at a natural tempo
            assert 0.3 <= c.end - c.start <= 1.0, c
            t, q, _ = run.telemetry
            pitch = q[(t >= c.start) & (t <= c.end + 0.2), list(channel_servos("head"))[1]]
            assert count_swings(pitch, below=True) == 1
    elif tid == 4:
        follows(one("speak", text="Hello"), one("face_emo", emo="smile"))
    elif tid == 5:
        follows(one("head_act", action="nod"), one("wave"))
    elif tid == 6:
        follows(one("chest_expansion_exercise"), one("fly_rub_hands"))
    elif tid == 7:
        leans = f("body_lean")
        assert [c.args["direction"] for c in leans] == ["left", "right"] * 3
        for a, b in itertools.pairwise(leans):
            follows(a, b)
        follows(leans[-1], one("speak"), within=SPEECH_PROMPT_S)
    elif tid == 8:
        order = [one("speak", text="Hello everyone"), one("shake_ear"), one("head_act", action="shake"),
                 one("sit", style="dog"), one("speak", text="Woof woof woof")]
        for a, b in itertools.pairwise(order):
            follows(a, b, within=SPEECH_PROMPT_S if b.function == "speak" else PROMPT_S)
    elif tid == 9:
        segs = [c for c in run.calls if c.function in ("run_distance", "rotate")]
        assert [c.function for c in segs] == ["run_distance", "rotate"] * 4
        for a, b in itertools.pairwise(segs):
            follows(a, b)  # strictly sequential
        s = run.report.summary
        gap = math.dist(s.base_end[:2], s.base_start[:2])
        turn = wrap180(s.base_end[2] - s.base_start[2])
        assert gap < 0.10 and abs(turn) < 35, f"square not closed: {gap * 100:.1f} cm, {turn:.1f} deg"
        for c in segs:  # each side ~20 cm, each corner ~90 deg right
            if c.function == "run_distance":
                assert 0.15 <= run.moved_forward_m(c.start, c.end) <= 0.25
            else:
                assert -108 <= run.turned_deg(c.start, c.end) <= -72
    elif tid == 10:
        w, e = one("wriggle"), one("shake_ear")
        lasts(w, 3.0)
        lasts(e, 2.0)
        follows(w, e)
    elif tid == 11:
        ks = f("single_leg_knock")
        assert [(c.args["leg"], c.args["times"]) for c in ks] == [(1, 1), (2, 2), (3, 3), (4, 4)]
        for a, b in itertools.pairwise(ks):
            follows(a, b)
    elif tid == 12:
        head, rot = one("head_pose", yaw=-90.0), one("rotate", angle=180.0)
        follows(head, rot)
        turned = run.turned_deg(rot.start, rot.end)
        assert 144 <= turned <= 216, f"turned {turned:.1f} deg, not 180 deg to the left"
    elif tid == 13:
        sh, cr = one("shake_ass", speed=100, times=2), one("creep", direction="backward", speed=50)
        follows(sh, cr)
        assert run.moved_forward_m(cr.start, cr.end) < -0.03  # it crept backward
    elif tid == 14:
        sp, sm = one("speak", text="Hello"), one("face_emo", emo="smile")
        # "Hello" is dispatched with the smile, but speech is synthesised (wall clock) before it is
        # scheduled while the lockstep board clock runs on, so it may start a little later
        together(sp, sm, within=SPEECH_PROMPT_S)
        overlap(sp, sm)
    elif tid == 15:
        cs = [one("face_emo", emo="happy"), one("head_act"), one("push_up"), one("shake_ear")]
        assert len({c.channel for c in cs}) == 4
        # all four run at once; each starts as soon as its token has streamed in
        # (test_simultaneous_when_buffered shows they start together when the tokens arrive together)
        assert max(c.start for c in cs) < min(c.end for c in cs)
        text, pos = "".join(ch for _, ch in run.report.token_times), 0
        for c in cs:
            pos = text.index("/>", text.index(f"<{c.function}", pos)) + 2
            arrived = _arrival(run, pos)
            assert 0 <= c.start - arrived <= 0.2, f"{c.function} started {c.start - arrived:.3f} s after its token"
    elif tid == 16:
        st, nod = one("stand", posture="backward"), one("head_act", duration=3.0)
        assert st.start <= nod.start
        lasts(nod, 3.0, tol=0.1)
        # stand is self-closing: it reaches the stance and nothing undoes it while the nod runs
        assert [c for c in run.calls if c.channel == "body"] == [st]
        _holds_backward_stance(run, max(st.end, nod.start), nod.end)
    elif tid == 17:
        fr, ears = one("face_emo", emo="very_frustrated"), one("shake_ear", duration=6.0)
        lasts(ears, 6.0)
        overlap(fr, ears)
    elif tid == 18:
        rot, bgm, sh = one("rotate"), one("play_bgm"), one("shake_ass")
        follows(rot, bgm)
        follows(rot, sh)
        together(bgm, sh)
        overlap(bgm, sh)
        turned = run.turned_deg(rot.start, rot.end)
        assert 288 <= turned <= 432, f"spun {turned:.1f} deg, not a full turn"
    elif tid == 19:
        ears, bgm, wink = one("shake_ear"), one("play_bgm"), one("face_emo", emo="wink")
        overlap(ears, bgm)
        before(ears, wink)
        follows(bgm, wink)
    elif tid == 20:
        ear, mv, bgm, pu = one("ear_state", state="inquisitive"), one("move_forward"), one("play_bgm"), one("push_up")
        follows(ear, mv)
        together(mv, bgm)
        overlap(mv, bgm)
        before(mv, pu)
        follows(bgm, pu)
    elif tid == 21:
        pu, bgm, happy, sp = one("push_up", duration=3.0), one("play_bgm"), one("face_emo", emo="happy"), one("speak")
        lasts(pu, 3.0, tol=0.1)
        overlap(pu, bgm)
        for a in (pu, bgm):
            before(a, happy)
            before(a, sp)
        follows(bgm, happy)
        overlap(happy, sp)
    elif tid == 22:
        bgm1, bgm2 = f("play_bgm")
        stand, strides, sit = one("stand"), one("move_strides", times=2), one("sit")
        overlap(bgm1, stand)
        before(stand, strides)
        follows(bgm1, strides)
        follows(strides, bgm2)
        follows(strides, sit)
        together(bgm2, sit)
    elif tid == 23:
        nod, back = one("head_act", action="nod"), one("move_strides", direction="backward", times=3)
        assert nod.persistent and not back.persistent
        assert nod.start <= back.start
        stop = nod.end - back.end  # the END of the nod's smooth return, after the last stride
        assert 0 <= stop <= 0.2, f"nodding stopped {stop:.3f} s after the last stride"
        # the cut itself: the FLUSH of the head servos, from the first frame of the return (one cut: a FLUSH
        # whose ACK came late, as from a slow QEMU board on a loaded machine, is re-sent with the same fields)
        head = mask_of(channel_servos("head"))
        cuts = sorted({f["from_us"] * 1e-6 for f in run.host_sent("FLUSH") if f["mask"] == head})
        assert len(cuts) == 1 and 0 <= cuts[0] - back.end <= 0.15, (cuts, back.end)
        assert run.moved_forward_m(back.start, back.end) < -0.03  # the strides went backward
    elif tid == 24:
        sh, bgm, calm = one("shake_ass"), one("play_bgm", duration=10.0), one("face_emo", emo="calm", duration=3.0)
        assert sh.persistent and sh.start <= bgm.start and sh.start <= calm.start
        lasts(bgm, 10.0)
        lasts(calm, 3.0)
        stop = sh.end - max(bgm.end, calm.end)
        assert 0 <= stop <= 0.3, f"shaking stopped {stop:.3f} s after music and face"
    elif tid == 25:
        bgm, st, nod = one("play_bgm"), one("stand"), one("head_act", duration=3.0)
        assert bgm.persistent and st.persistent and not nod.persistent
        lasts(nod, 3.0, tol=0.1)
        assert 0 <= st.end - nod.end <= 0.3 and 0 <= bgm.end - st.end <= 0.3  # each parent ends right after its child
    elif tid == 26:
        bgm = one("play_bgm")
        ears, nods, strides = f("shake_ear"), f("head_act", action="nod"), one("move_strides", times=2)
        assert len(ears) == 3 and len(nods) == 3 and bgm.persistent
        for group in (ears, nods):  # calls on one channel flow into each other: no gap, no stop
            for a, b in itertools.pairwise(group):
                follows(a, b, within=FRAME_S + 1e-9)
        follows(ears[-1], nods[0])
        follows(nods[-1], strides)
        assert bgm.start <= ears[0].start and 0 <= bgm.end - strides.end <= 0.3
        # one call = one gesture, counted in the measured joint angles
        t, q, _ = run.telemetry
        pitch = q[(t >= nods[0].start) & (t <= nods[-1].end + 0.2), list(channel_servos("head"))[1]]
        ear = q[(t >= ears[0].start) & (t <= ears[-1].end + 0.2), list(channel_servos("ears"))[0]]
        assert count_swings(pitch, below=True) == 3, "the head did not nod exactly three times"
        assert count_swings(ear, below=False) == 3, "the ears did not flap exactly three times"
    elif tid == 27:
        dog, head, sur = one("shake_like_dog"), one("head_pose", yaw=-90.0), one("face_emo", emo="surprise")
        assert dog.persistent
        follows(head, sur)
        assert dog.start <= head.start and 0 <= dog.end - sur.end <= 0.3
    elif tid == 28:
        st, wink, cap = one("stand", posture="forward"), one("face_emo", emo="wink_right", duration=5.0), one("capture")
        assert st.persistent
        lasts(wink, 5.0)
        assert cap.start < wink.end and wink.start < cap.end  # the photo is taken while winking
        if firmware == "python":
            assert run.report.summary.extra["captures"], "no image came back from the camera"
        else:  # the C firmware NACKs CAMERA_CAPTURE with NO_RENDERER: the call fails in one line, the rest runs
            assert no_renderer(run) == [cap] and not run.report.summary.extra["captures"]
        assert 0 <= st.end - max(wink.end, cap.end) <= 0.3
    elif tid in (29, 30):
        dog, ears = one("shake_like_dog"), one("shake_ear", duration=3.0)
        nod, happy = one("head_act", action="nod"), one("face_emo", emo="happy")
        assert dog.persistent
        lasts(ears, 3.0)
        overlap(nod, happy)
        if tid == 29:  # both released together by the end of the ear shake
            follows(ears, nod)
            follows(ears, happy)
            together(nod, happy)
        else:
            before(nod, ears)
            follows(happy, ears)
        assert 0 <= dog.end - max(c.end for c in (ears, nod, happy)) <= 0.3
    else:  # pragma: no cover
        raise AssertionError(f"no check for task {tid}")


def _arrival(run: E2ERun, upto: int) -> float:
    """Board time at which the first ``upto`` characters of the program had streamed in."""
    n = 0
    for t, chunk in run.report.token_times:
        n += len(chunk)
        if n >= upto:
            return t
    raise AssertionError("token not found")


def _holds_backward_stance(run: E2ERun, start: float, end: float) -> None:
    """Measured leg angles stay at the backward stance from ``start`` to ``end``."""
    from robots.coco.motions import STAND_POSTURES

    t, q, _ = run.telemetry
    legs = list(channel_servos("body"))
    during = q[(t >= start) & (t <= end)][:, legs]
    assert len(during) > 50
    err = np.degrees(np.abs(during - STAND_POSTURES["backward"])).max()
    assert err < 3.0, f"the legs left the backward stance by {err:.1f} deg during the nod"
