"""A re-sent HELLO continues its host's numbering; only a HELLO numbered 0 starts a new host's.

Under load the host re-sends HELLO before the first CAPS arrives; a lost re-sent HELLO is then a
sequence gap like any other (CI, task 10 under the paper's faults: HELLO 0 in, HELLO 1 lost, HELLO 2
in, and a board that restarted its numbering at every HELLO counted one gap fewer than its own frame
log showed). The Python board and the C firmware count alike, read from their ``board: faults`` line (a fault rate of 1e-12: the line, no fault).
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from protocol.codec import SCHEMA_HASH
from protocol.messages import PROTOCOL_VERSION, Advance, Caps, Hello, Telemetry

from .wire import Wire


def _seq_gaps(stderr: Path) -> int:
    line = next(x for x in stderr.read_text().splitlines() if x.startswith("board: faults "))
    return int(json.loads(line.removeprefix("board: faults "))["board_detected"]["seq_gaps"])


@pytest.mark.parametrize("firmware", ["python", "c"])
def test_a_lost_resent_hello_is_a_gap_and_a_new_host_starts_afresh(firmware: str, tmp_path: Path) -> None:
    err = tmp_path / "board.stderr"
    w = Wire(["--lockstep", "--firmware", firmware, "--faults", "drop=1e-12", "--fault-seed", "1"], err)
    try:
        w.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), seq=0)
        w.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), seq=2)  # the re-sent HELLO numbered 1 was lost
        w.wait(lambda: len(w.of(Caps)) == 2, what="two CAPS")
        w.send(Advance(20_000), seq=3)
        w.wait(lambda: any(t.board_time_us >= 20_000 for t in w.of(Telemetry)), what="telemetry")
        # a new host: numbered from 0 again, no gap back to 3; then one more lost (1) before 2
        w.send(Hello(PROTOCOL_VERSION, SCHEMA_HASH, 0), seq=0)
        w.send(Advance(40_000), seq=2)
        w.wait(lambda: any(t.board_time_us >= 40_000 for t in w.of(Telemetry)), what="telemetry")
    finally:
        status = w.close()
    assert status == 130, err.read_text()[-2000:]
    assert _seq_gaps(err) == 2, err.read_text()[-2000:]
