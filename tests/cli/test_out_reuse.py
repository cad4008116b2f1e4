"""A run's folder holds only this run's artefacts, and a run refused before it starts leaves none.

A fresh user's reports: ``--out`` reused from a finished demo kept its run.mp4, timeline.png and joints.png,
and the "artefacts in" line named them as this run's; ``--link can:slcan:/dev/nonexist`` exited 2 but left
the folder with an empty host_frames.log; a bound's line gave the time into the run as "board time".
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(240)

ROOT = Path(__file__).resolve().parents[2]


def _ghostshell(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host", *args], capture_output=True, text=True, timeout=200,
                          stdin=subprocess.DEVNULL, cwd=ROOT)


def test_clearing_removes_the_run_artefacts_and_nothing_else(tmp_path: Path) -> None:
    from host.commands.outarg import clear_run_artefacts
    from host.link.canlog import CAN_LOG_SUFFIXES
    from host.run.artefacts import RUN_ARTEFACTS

    assert {f"host_frames{s}" for s in CAN_LOG_SUFFIXES} <= set(RUN_ARTEFACTS)  # every frame log a CAN run writes
    for name in ("run.mp4", "summary.json", "board_frames.asc", "capture_session_2.png", "notes.txt", "run.mp4.bak"):
        (tmp_path / name).write_text("old")
    (tmp_path / "speech").mkdir()
    (tmp_path / "speech" / "index.jsonl").write_text("{}")
    assert clear_run_artefacts(tmp_path) == ["board_frames.asc", "capture_session_2.png", "run.mp4", "summary.json"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt", "run.mp4.bak", "speech"]
    assert clear_run_artefacts(tmp_path / "nosuch") == []


def test_a_reused_out_folder_keeps_only_this_runs_artefacts(tmp_path: Path) -> None:
    out = tmp_path / "reuse"
    out.mkdir()
    for name in ("run.mp4", "timeline.png", "joints.png", "summary.json", "capture_session_1.png", "notes.txt"):
        (out / name).write_text("an earlier CoCo run")
    r = _ghostshell("run", "--robot", "arm", "--xml", "<grip/>", "--lockstep", "--no-live", "--no-plots",
                    "--out", str(out))
    assert r.returncode == 0, r.stderr[-3000:]
    notes = [ln for ln in r.stdout.splitlines() if "held an earlier run's artefacts" in ln]
    assert len(notes) == 1 and notes[0].startswith("ghostshell run: ") and "run.mp4" in notes[0], r.stdout
    for gone in ("run.mp4", "timeline.png", "joints.png", "capture_session_1.png"):
        assert not (out / gone).exists(), gone
    assert (out / "notes.txt").read_text() == "an earlier CoCo run"  # not the run's: left alone
    assert json.loads((out / "summary.json").read_text())["outcome"] == "done"  # this run's
    listed = r.stdout.rsplit("artefacts in", 1)[1].split()
    assert "run.mp4" not in listed and "timeline.png" not in listed and "summary.json" in listed, listed


@pytest.mark.parametrize("link", ["can:slcan:/dev/nonexist", "can:slcan:/dev/null", "can:bogus:x"])
def test_a_can_link_refused_when_opened_leaves_no_run_folder(tmp_path: Path, link: str) -> None:
    out = tmp_path / "bad"
    r = _ghostshell("run", "--xml", "<grip/>", "--robot", "arm", "--link", link, "--out", str(out))
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode == 2 and len(err) == 1 and "cannot open CAN bus" in err[0], r.stderr[-3000:]
    assert not out.exists(), list(out.iterdir())


def test_a_stopped_runs_line_gives_the_board_clock_of_the_table_and_timeline(tmp_path: Path) -> None:
    out = tmp_path / "run"
    r = _ghostshell("run", "--xml", '<head_act action="nod" duration="30"/>', "--lockstep", "--no-live", "--no-plots",
                    "--max-board-s", "1", "--out", str(out))
    assert r.returncode == 1, r.stderr[-3000:]
    t0 = json.loads((out / "timeline.json").read_text())["t0"]
    duration = json.loads((out / "summary.json").read_text())["duration_s"]
    assert t0 > 0.05  # the turn begins after the move to the start pose: the two clocks differ
    m = re.search(r"at board time (\d+\.\d\d) s \((\d+\.\d\d) s into the run\)", r.stderr)
    assert m is not None, r.stderr
    assert float(m[1]) == pytest.approx(t0 + duration, abs=0.006) and float(m[2]) == pytest.approx(duration, abs=0.006)
