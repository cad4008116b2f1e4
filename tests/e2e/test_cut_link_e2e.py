"""A cut link on a REALTIME emulated board over a pty (``--faults cut=START+LENGTH`` on both directions).

The board's own report lines (``board: watchdog hold|crouch at board time ...``) and the host's
frame log are the evidence; the run itself ends on the condition (no sleeps): a long cut ends it
with one LinkError naming the latched fault, a short one (shorter than watchdog + crouch delay)
only makes the board hold and the run completes.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from firmware_sim.config import BoardConfig
from host.link.errors import LinkError

from .conftest import run_e2e

PROGRAM = '<move_strides direction="forward" times="10"/>'  # ~7 s of walking: the cut falls inside it
EVENT = re.compile(r"board: watchdog (hold|crouch) at board time ([0-9.]+) s, ([0-9.]+) s after the last valid message")


def _events(out: Path) -> list[tuple[str, float, float]]:
    return [(m[1], float(m[2]), float(m[3])) for m in EVENT.finditer((out / "board.stderr").read_text())]


def test_long_cut_holds_crouches_latches_and_ends_the_run(tmp_path: Path) -> None:
    cfg = BoardConfig()
    tick_s = 1.0 / cfg.rate_hz
    with pytest.raises(LinkError, match="link lost.*latched its watchdog fault") as e:
        run_e2e(PROGRAM, tmp_path, lockstep=False, faults="cut=2+2.5")
    assert "\n" not in str(e.value)  # one message
    ev = _events(tmp_path)
    assert [k for k, _, _ in ev] == ["hold", "crouch"], ev
    (_, hold_t, hold_silent), (_, crouch_t, crouch_silent) = ev
    # measured on board time: HOLD within watchdog + one tick of silence, CROUCH crouch_after later
    assert cfg.watchdog_ms / 1000 < hold_silent <= cfg.watchdog_ms / 1000 + tick_s + 1e-9
    assert crouch_t - hold_t == pytest.approx(cfg.crouch_after_ms / 1000, abs=tick_s + 1e-9)
    # after the link came back every report still carries the latched fault (nothing cleared it)
    tel = [json.loads(line) for line in (tmp_path / "host_frames.jsonl").read_text().splitlines()
           if '"TELEMETRY"' in line]
    flags = [(r["fields"]["board_time_us"], r["fields"]["faults"]) for r in tel if r["dir"] == "rx"]
    after = [f for t, f in flags if t >= crouch_t * 1e6]
    assert after and all("WATCHDOG_FAULT" in f for f in after)


def test_short_cut_only_holds_and_the_run_resumes(tmp_path: Path) -> None:
    run = run_e2e(PROGRAM, tmp_path, lockstep=False, faults="cut=2+0.6")
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["outcome"] == "done" and {c.outcome for c in run.calls} == {"done"}
    ev = _events(tmp_path)
    assert [k for k, _, _ in ev] == ["hold"], ev  # held, never crouched: the next frame ended the hold
    assert summary["extra"]["faults"]["board"]["board_detected"]["watchdog_trips"] == 1
