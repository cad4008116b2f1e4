"""Hostile or runaway output: deep nesting is refused past a limit, long same-channel queues stay ordered."""

from __future__ import annotations

import pytest

from host.shell.scheduler import MAX_DEPTH

pytestmark = pytest.mark.anyio


async def test_nesting_past_the_limit_fails_those_elements_and_keeps_the_rest(coco) -> None:
    shell, _ = coco()
    depth = MAX_DEPTH + 20
    program = "<wait>" * depth + '<head_act duration="1"/>' + "</wait>" * depth + "<wave/>"
    r = await shell.run_text(program)
    refused = [x for x in r.timeline if x.outcome == "failed"]
    # the waits past the limit and the nod inside them (it is deeper still)
    assert len(refused) == depth - MAX_DEPTH + 1 and all("nested deeper" in x.error for x in refused)
    assert r.timeline.one("head_act").outcome == "failed"
    waits = [x for x in r.timeline.find("wait") if x.outcome == "done"]
    assert len(waits) == MAX_DEPTH
    wave = r.timeline.one("wave")
    assert wave.outcome == "done" and r.error is None  # the stream goes on after the refused part


async def test_same_channel_queue_waits_for_a_pending_parent_it_is_not_inside(coco) -> None:
    # The second nod is queued behind the parent nod AND its child (both on the head channel);
    # the parent's reset takes 0.5 s after the child ends, and the queue must wait for it too.
    shell, _ = coco(reset_seconds=0.5)
    r = await shell.run_text('<head_act action="shake"><head_pose yaw="10"/></head_act><head_act duration="2"/>'
                             '<head_act duration="1"/>')
    parent, pose = r.timeline.one("head_act", action="shake"), r.timeline.one("head_pose")
    second, third = r.timeline.one("head_act", duration=2.0), r.timeline.one("head_act", duration=1.0)
    assert parent.start <= pose.start and pose.end <= parent.end
    assert parent.end == pose.end + 0.5
    assert second.start >= parent.end and third.start == second.end == second.start + 2


async def test_a_long_queue_on_one_channel_runs_in_order(coco) -> None:
    shell, _ = coco()
    n = 400
    r = await shell.run_text('<face_emo emo="happy" duration="0.5"/>' * n)
    faces = r.timeline.find("face_emo")
    assert len(faces) == n and all(f.outcome == "done" for f in faces)
    assert [f.start for f in faces] == [0.5 * i for i in range(n)]
