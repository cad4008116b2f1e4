"""A function token moves a servo at once on a realtime board (issue 9 §1), checked structurally.

A new call's first frame is due at the board's now + the link's measured latency + one tick,
inside the part of the frame grid the streamer has already sent (the hold): the host FLUSHes the
servos it takes over from that time, sends the first frame, and re-sends those servos' frames for
the rest of the grid already sent. Wall-clock numbers belong in ``bench/bench_latency.py``; this
test checks the order of messages in the host's frame log and that the board applied everything
(no LATE frame, nothing dropped), which hold on any machine.
"""

from __future__ import annotations

from protocol.framelog import iter_records
from robots.coco.motions import channel_servos

from .conftest import mask_of, run_e2e

import pytest

pytestmark = pytest.mark.realtime  # tests/support/realtime_lock.py


def test_new_call_replaces_the_hold_instead_of_waiting_out_the_lookahead(tmp_path) -> None:
    run = run_e2e('<head_act action="nod"/>', tmp_path, lockstep=False, settle_s=0.2)
    nod = run.one("head_act")
    assert nod.outcome == "done" and run.report.summary.extra["link"]["late"] == 0
    assert run.report.summary.extra["link"]["dropped"] == 0
    head = mask_of(channel_servos("head"))
    with open(run.out / "host_frames.jsonl", encoding="utf-8") as f:
        sent = [r for r in iter_records(f) if r["dir"] == "tx" and r.get("type") in ("FLUSH", "SERVO_FRAME")]
    i = next(k for k, r in enumerate(sent) if r["type"] == "FLUSH" and r["fields"]["mask"] == head)
    # the first frame, then the FLUSH of its servos from just after its time (BoardFrameLink.send_start)
    first = sent[i - 1]["fields"]
    cut = first["apply_at_us"]
    assert sent[i - 1]["type"] == "SERVO_FRAME" and first["mask"] == head and sent[i]["fields"]["from_us"] == cut + 1
    horizon = max(r["fields"]["apply_at_us"] for r in sent[:i - 1] if r["type"] == "SERVO_FRAME")
    assert cut < horizon, "the call waited for the frames already sent instead of replacing them"
    resent = [r["fields"] for r in sent[i + 1:] if r["type"] == "SERVO_FRAME" and r["fields"]["mask"] == head]
    assert resent and all(cut < r["apply_at_us"] <= horizon for r in resent)
    assert abs(nod.start - cut * 1e-6) < 1e-6  # the call's measured start is that first frame
