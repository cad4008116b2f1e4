"""All 30 ground-truth programs of the paper on fake CoCo functions (virtual clock).

Durations come from host.testing.quadruped (nod 1 s, stride 1 s, bgm clip 5 s,
speech 0.1 s/char ...). Each check asserts the ordering the instruction demands.
"""

from __future__ import annotations


import pytest

from robots.coco.tasks import load_tasks

TASKS = {i: {"id": i, "ground_truth": t.ground_truth} for i, t in load_tasks().items() if t.ground_truth}

pytestmark = pytest.mark.anyio


def before(a, b):
    """a ends no later than b starts."""
    assert a.end is not None and b.start is not None and a.end <= b.start, (a, b)


def overlap(a, b):
    assert a.start < b.end and b.start < a.end, (a, b)


def check(tid, tl):
    f = tl.find
    one = tl.one
    if tid in (1, 2, 3):
        assert len(tl) == 1 and tl.records[0].start == 0
    elif tid == 4:
        before(one("speak", text="Hello"), one("face_emo", emo="smile"))
    elif tid == 5:
        nod, wave = one("head_act", action="nod"), one("wave")
        assert wave.start == nod.end == 1.0
    elif tid == 6:
        before(one("chest_expansion_exercise"), one("fly_rub_hands"))
    elif tid == 7:
        leans = f("body_lean")
        assert [r.args["direction"] for r in leans] == ["left", "right"] * 3
        for a, b in zip(leans, leans[1:]):
            before(a, b)
        before(leans[-1], one("speak"))
    elif tid == 8:
        order = [one("speak", text="Hello everyone"), one("shake_ear"), one("head_act", action="shake"),
                 one("sit", style="dog"), one("speak", text="Woof woof woof")]
        for a, b in zip(order, order[1:]):
            before(a, b)
    elif tid == 9:
        rs = [r for r in tl if r.function in ("run_distance", "rotate")]
        assert [r.function for r in rs] == ["run_distance", "rotate"] * 4
        for a, b in zip(rs, rs[1:]):
            assert a.end == b.start
    elif tid == 10:
        w, e = one("wriggle"), one("shake_ear")
        assert (w.start, w.end, e.start, e.end) == (0, 3, 3, 5)
    elif tid == 11:
        ks = f("single_leg_knock")
        assert [(r.args["leg"], r.args["times"]) for r in ks] == [(1, 1), (2, 2), (3, 3), (4, 4)]
        for a, b in zip(ks, ks[1:]):
            before(a, b)
    elif tid == 12:
        before(one("head_pose", yaw=-90.0), one("rotate", angle=180.0))
    elif tid == 13:
        s, c = one("shake_ass", speed=100, times=2), one("creep", direction="backward", speed=50)
        before(s, c)
    elif tid == 14:
        sp, sm = one("speak", text="Hello"), one("face_emo", emo="smile")
        assert sp.start == sm.start == 0
        overlap(sp, sm)
    elif tid == 15:
        rs = [one("face_emo", emo="happy"), one("head_act"), one("push_up"), one("shake_ear")]
        assert all(r.start == 0 for r in rs)
        assert len({r.channel for r in rs}) == 4
    elif tid == 16:
        st, nod = one("stand", posture="backward"), one("head_act", duration=3.0)
        assert st.start == nod.start == 0 and nod.end == 3
        # the backward stance is the last body command: nothing undoes it while the nod runs
        assert not [r for r in tl if r.channel == "body" and r.start is not None and r.start > st.start]
    elif tid == 17:
        fr, ears = one("face_emo", emo="very_frustrated"), one("shake_ear", duration=6.0)
        assert fr.start == ears.start == 0 and ears.end == 6
    elif tid == 18:
        rot, bgm, sh = one("rotate"), one("play_bgm"), one("shake_ass")
        before(rot, bgm)
        before(rot, sh)
        assert bgm.start == sh.start
        overlap(bgm, sh)
    elif tid == 19:
        ears, bgm, wink = one("shake_ear"), one("play_bgm"), one("face_emo", emo="wink")
        overlap(ears, bgm)
        before(ears, wink)
        before(bgm, wink)
    elif tid == 20:
        ear, mv, bgm, pu = one("ear_state", state="inquisitive"), one("move_forward"), one("play_bgm"), one("push_up")
        before(ear, mv)
        overlap(mv, bgm)
        before(mv, pu)
        before(bgm, pu)
    elif tid == 21:
        pu, bgm, happy, sp = one("push_up", duration=3.0), one("play_bgm"), one("face_emo", emo="happy"), one("speak")
        overlap(pu, bgm)
        for a in (pu, bgm):
            before(a, happy)
            before(a, sp)
        overlap(happy, sp)
    elif tid == 22:
        bgm1, bgm2 = f("play_bgm")
        stand, strides, sit = one("stand"), one("move_strides", times=2), one("sit")
        overlap(bgm1, stand)
        before(bgm1, strides)
        before(stand, strides)
        before(strides, bgm2)
        before(strides, sit)
        assert bgm2.start == sit.start
    elif tid == 23:
        nod, back = one("head_act", action="nod"), one("move_strides", direction="backward", times=3)
        assert nod.persistent and not back.persistent
        assert nod.start == back.start == 0 and nod.end == back.end == 3
    elif tid == 24:
        sh, bgm, calm = one("shake_ass"), one("play_bgm", duration=10.0), one("face_emo", emo="calm", duration=3.0)
        assert sh.persistent and sh.start == bgm.start == calm.start == 0
        assert calm.end == 3 and bgm.end == 10 and sh.end == max(bgm.end, calm.end)
    elif tid == 25:
        bgm, st, nod = one("play_bgm"), one("stand"), one("head_act", duration=3.0)
        assert bgm.persistent and st.persistent
        assert nod.end == 3 and st.end == 3 and bgm.end == 3 and st.end <= bgm.end
    elif tid == 26:
        bgm = one("play_bgm")
        ears, nods, strides = f("shake_ear"), f("head_act", action="nod"), one("move_strides", times=2)
        assert len(ears) == 3 and len(nods) == 3
        seq = [*ears, *nods, strides]
        for a, b in zip(seq, seq[1:]):
            before(a, b)
        assert bgm.start == 0 and bgm.end == strides.end
    elif tid == 27:
        dog, head, sur = one("shake_like_dog"), one("head_pose", yaw=-90.0), one("face_emo", emo="surprise")
        before(head, sur)
        assert dog.start == 0 and dog.end == sur.end
    elif tid == 28:
        st, wink, cap = one("stand", posture="forward"), one("face_emo", emo="wink_right", duration=5.0), one("capture")
        assert wink.start == cap.start == 0
        assert st.end == max(wink.end, cap.end) == 5
    elif tid in (29, 30):
        dog, ears = one("shake_like_dog"), one("shake_ear", duration=3.0)
        nod, happy = one("head_act", action="nod"), one("face_emo", emo="happy")
        assert nod.start == happy.start
        if tid == 29:
            before(ears, nod)
        else:
            before(nod, ears)
            before(happy, ears)
        assert dog.end == max(r.end for r in (ears, nod, happy))
    else:  # pragma: no cover
        raise AssertionError(f"no check for task {tid}")


@pytest.mark.parametrize("tid", sorted(TASKS))
async def test_ground_truth_task(tid, coco):
    shell, impl = coco()
    result = await shell.run_text(TASKS[tid]["ground_truth"])
    assert result.error is None
    assert all(r.outcome == "done" for r in result.timeline), result.timeline.table()
    check(tid, result.timeline)


@pytest.mark.parametrize("tid", sorted(TASKS))
async def test_ground_truth_task_streamed_in_small_chunks(tid, coco):
    """The same programs fed 3 characters at a time: identical timelines."""
    shell, _ = coco()
    text = TASKS[tid]["ground_truth"]
    whole = await shell.run_text(text)
    parts = await shell.run_text([text[i : i + 3] for i in range(0, len(text), 3)])
    key = lambda tl: [(r.function, r.args, r.path, r.start, r.end, r.outcome) for r in tl]  # noqa: E731
    assert key(parts.timeline) == key(whole.timeline)


SYNC_FIRST = {
    # task id: Sync-First program equivalent to the Async-First ground truth
    5: '<head_act action="nod"/><wave/>',
    14: '<async>Hello<face_emo emo="smile"/></async>',
    18: "<rotate/><async><play_bgm/><shake_ass/></async>",
    19: '<async><shake_ear/><play_bgm/></async><face_emo emo="wink"/>',
    21: '<async><push_up duration="3"/><play_bgm/></async><async><face_emo emo="happy"/>What are you doing</async>',
    23: '<head_act action="nod"><move_strides direction="backward" times="3"/></head_act>',
    24: '<shake_ass><async><play_bgm duration="10"/><face_emo emo="calm" duration="3"/></async></shake_ass>',
    26: ('<play_bgm><shake_ear/><shake_ear/><shake_ear/><head_act action="nod"/><head_act action="nod"/>'
         '<head_act action="nod"/><move_strides direction="forward" times="2"/></play_bgm>'),
}


@pytest.mark.parametrize("tid", sorted(SYNC_FIRST))
async def test_sync_first_equivalent(tid, coco):
    shell, _ = coco(mode="sync-first")
    result = await shell.run_text(SYNC_FIRST[tid])
    assert all(r.outcome == "done" for r in result.timeline), result.timeline.table()
    check(tid, result.timeline)


async def test_sync_first_runs_ground_truth_sequentially(coco):
    """Task 15 (parallel under Async-First) is strictly sequential under Sync-First."""
    shell, _ = coco(mode="sync-first")
    tl = (await shell.run_text('<face_emo emo="happy"/><head_act action="nod"/><push_up/><shake_ear/>')).timeline
    assert all(r.channel == "main" for r in tl)
    for a, b in zip(tl.records, tl.records[1:]):
        assert a.end == b.start
