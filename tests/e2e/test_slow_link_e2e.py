"""A realtime run over a link slower than the host's lookahead still streams, in time.

``delay=80`` adds 80 ms to every frame each way (``protocol.faults``), so the uplink p99 the host
measures (~80 ms) exceeds its 60 ms lookahead. Every realtime top-up used to skip the grid times a
frame sent now could no longer reach, past its own horizon, and send nothing: the run ended with
"the host sent no servo frame for 10 s" (seen first under load 5 on this machine, where late
TIME_SYNC replies inflated the uplink). Now the horizon reaches one period past the first time still
in reach (:meth:`host.motion.streamer.FrameStreamer.top_up`). No sleeps: the run ends when the
program is done.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from support.realtime_lock import realtime_part_done

from .conftest import run_e2e

pytestmark = pytest.mark.realtime  # tests/support/realtime_lock.py

PROGRAM = '<head_act action="nod"/><move_strides direction="forward" times="2"/>'


def test_a_link_slower_than_the_lookahead_still_streams_in_time(tmp_path: Path) -> None:
    run = run_e2e(PROGRAM, tmp_path, lockstep=False, faults="delay=80")
    realtime_part_done()
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["outcome"] == "done" and {c.outcome for c in run.calls} == {"done"}, run.table()
    link = summary["extra"]["link"]
    assert link["frames_sent"] > 100, link  # ~2 s of walking at 100 frames/s, the nod before it
    assert link["late"] == 0 and link["frame_nacks"] == 0, link  # each sent in time by the link's own p99
