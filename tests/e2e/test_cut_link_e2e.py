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
from host.run.link_health import link_health_line
from host.run.runner import ended_report

from .conftest import run_e2e

PROGRAM = '<move_strides direction="forward" times="10"/>'  # ~7 s of walking: the cut falls inside it
EVENT = re.compile(r"board: watchdog (hold|crouch) at board time ([0-9.]+) s, ([0-9.]+) s after the last valid message")


def _events(out: Path) -> list[tuple[str, float, float]]:
    return [(m[1], float(m[2]), float(m[3])) for m in EVENT.finditer((out / "board.stderr").read_text())]


@pytest.mark.realtime
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
    # the run the link ended still leaves its report: how it ended, its calls, what was injected and detected
    report = ended_report(e.value)
    assert report is not None and report.out == tmp_path
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["outcome"] == "link_lost" and summary["extra"]["link_error"] == str(e.value)
    faults = summary["extra"]["faults"]
    assert faults["host_detected"]["link_lost"] == str(e.value)
    injected = faults["board"]["injected"]  # the board's own report (it printed it when the host stopped it)
    assert {d["direction"] for d in injected} == {"host->board", "board->host"} and all(d["injected"]["cut"] > 0 for d in injected)
    assert faults["board"]["board_detected"]["watchdog_trips"] >= 1
    timeline = json.loads((tmp_path / "timeline.json").read_text())
    (walk,) = [c for c in timeline["calls"] if c["function"] == "move_strides"]
    # cut short: failed by the loss (it was waiting for the board) or cancelled with it; either way it names it
    assert walk["start"] is not None and walk["outcome"] in ("failed", "cancelled") and "link lost" in walk["error"]
    assert summary["outcomes"]["failed"] + summary["outcomes"]["cancelled"] == 1 and summary["outcomes"]["done"] == 0


@pytest.mark.realtime
def test_short_cut_only_holds_and_the_run_resumes(tmp_path: Path) -> None:
    run = run_e2e(PROGRAM, tmp_path, lockstep=False, faults="cut=2+0.6")
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["outcome"] == "done" and {c.outcome for c in run.calls} == {"done"}
    ev = _events(tmp_path)
    assert [k for k, _, _ in ev] == ["hold"], ev  # held, never crouched: the next frame ended the hold
    assert summary["extra"]["faults"]["board"]["board_detected"]["watchdog_trips"] == 1
    # ``ghostshell run`` ends with a line that says so (the run itself is "done")
    health = link_health_line(summary["extra"])
    assert health is not None and health.startswith("link: 1 board watchdog trip (servos held)"), health
    assert "faults injected: cut=2+0.6" in health, health


@pytest.mark.realtime
def test_demo_cut_by_the_link_prints_one_message_and_keeps_its_report(tmp_path: Path) -> None:
    import subprocess
    import sys

    out = tmp_path / "demo"
    # a real process: pytest's log capture would hide a stray log line on stderr
    cap = subprocess.run([sys.executable, "-m", "host.cli", "demo", "--no-video", "--no-live", "--faults", "cut=1.5+1.5",
                          "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert cap.returncode == 1, cap.stderr
    ours = [line for line in cap.stderr.splitlines() if line.startswith("ghostshell demo:")]
    assert len(ours) == 1 and re.fullmatch(r"ghostshell demo: link lost: .*latched its watchdog fault.*", ours[0]), cap.stderr
    assert cap.stderr.strip().splitlines() == ours, cap.stderr  # nothing else on stderr (a fault log line came first)
    assert "ghostshell estop --link" in ours[0] and ours[0].endswith("--clear`")
    assert f"artefacts in {out}/:" in cap.stdout and "summary.json" in cap.stdout
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "link_lost" and ours[0] == f"ghostshell demo: {summary['extra']['link_error']}"
    assert all(d["injected"]["cut"] > 0 for d in summary["extra"]["faults"]["board"]["injected"])
    calls = json.loads((out / "timeline.json").read_text())["calls"]
    assert calls and sum(summary["outcomes"].values()) == len(calls)
    cut_short = [c for c in calls if c["outcome"] in ("failed", "cancelled")]
    assert cut_short and all("link lost" in c["error"] for c in cut_short)
    assert any(c["error"] == "link lost while queued" and c["start"] is None for c in cut_short)


def test_a_link_cut_from_the_start_still_reports_what_was_injected(tmp_path: Path) -> None:
    # lockstep: the board clock stays at 0 until the host reaches it, so a cut from 0 holds for good
    with pytest.raises(LinkError, match="no CAPS") as e:
        run_e2e(PROGRAM, tmp_path, faults="cut=0+5")
    # the board is there: the message says the run's own faults lost the handshake (it asked whether a
    # board was serving the port, as for a port nobody serves)
    assert "the board this run started is there: its --faults cut=0+5 lost the HELLO/CAPS exchange" in str(e.value)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["outcome"] == "link_lost" and summary["extra"]["link_error"] == str(e.value)
    assert sum(summary["outcomes"].values()) == 0  # nothing ran
    (to_board,) = [d for d in summary["extra"]["faults"]["board"]["injected"] if d["direction"] == "host->board"]
    assert to_board["injected"]["cut"] == to_board["units_in"] > 0  # every HELLO was cut
