"""A lockstep run is a function of its input: however the host is disturbed, the board receives the same
messages and does the same with them (issue 41).

Each robot runs one short program twice with ``ghostshell run --lockstep`` over a pty: once quiet, once
with a CPU hog per core, the host process SIGSTOPped 0.25 s every 0.5 s, and the host's control path
stalled at random (``GHOSTSHELL_STALLS``, seeded, :mod:`host.motion.stalls`). The board's frame log
(what it received, and every report it sent: board time, positions, ``buffer_fill``,
``last_applied_seq``, SIM_STATE) and its final TELEMETRY/SIM_STATE must be identical
(:mod:`tests.support.lockstep_identity`). Before, a host stalled ~1 s had its silence watchdog ADVANCE
the board past the frames due next, and heartbeats and repeated ADVANCEs went out on wall time.
The 20-disturbed-runs version is ``bench/bench_lockstep_identity.py``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.support.lockstep_identity import compare, run_lockstep
from tests.support.mesh_robot import write_mesh_arm

#: a short stall at most, so a disturbed run stays well under 30 s on 2 cores
STALLS = "seed={seed},p=0.05,max_s=0.3"

PROGRAMS = {
    "coco": ["--robot", "coco"],
    "arm": ["--robot", "arm"],
}
XML = {
    "coco": 'Hello. <head_act action="nod" duration="0.6"/><wave/>',  # the text is spoken (synthesis: wall time)
    "arm": '<pose name="home"/><joint_move joint="shoulder_pan" deg="30" duration="0.6"/>',
    "mesh_arm": '<pose name="home"/><joint_move joint="shoulder_pan" deg="30" duration="0.6"/>',
}


@pytest.mark.parametrize("robot", ["coco", "arm", "mesh_arm"])
def test_a_disturbed_lockstep_run_gives_the_board_what_a_quiet_one_does(robot: str, tmp_path: Path) -> None:
    if robot == "mesh_arm":
        args = ["--robots-dir", str(write_mesh_arm(tmp_path / "mesh")), "--robot", "mesh_arm"]
    else:
        args = PROGRAMS[robot]
    q = run_lockstep(tmp_path / "quiet", XML[robot], args)
    assert q.proc.returncode == 0, q.proc.stderr[-2000:]
    d = run_lockstep(tmp_path / "disturbed", XML[robot], args, disturb=True, stalls=STALLS.format(seed=len(robot)))
    assert d.proc.returncode == 0, d.proc.stderr[-2000:]
    assert d.stops >= 2  # the host was stopped while it streamed
    quiet, disturbed = q.record, d.record
    # the program ran to its end in both (a comparison of two stubs would prove nothing)
    assert quiet.counts().get("ServoFrame", 0) > 100 and quiet.end_us > 1_500_000, quiet.counts()
    assert min(quiet.end_us, disturbed.end_us) >= quiet.end_us - 100_000, (quiet.end_us, disturbed.end_us)
    assert compare(quiet, disturbed) == "identical", (quiet.counts(), disturbed.counts())
