"""run.mcap: every run records its channels live with foxglove-sdk; the mcap reader, ``log decode`` and
``replay`` read it back; bad input (an unwritable path, a killed run) costs the MCAP at most, never the run."""

from __future__ import annotations

import functools
import json
import logging
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from mcap.reader import make_reader

from host.cli import main as cli_main
from host.run.mcap_log import FLUSH_S
from host.run.mcap_read import McapRun, read_mcap_host_to_board
from host.run.replay import read_host_to_board
from robots.coco.tasks import load_tasks
from robots.registry import load_robot

from .conftest import run_e2e as _run_e2e

#: :func:`e2e.conftest.run_e2e` with its recording on (the other e2e runs make no run.mcap)
run_e2e = functools.partial(_run_e2e, mcap=True)

ROOT = Path(__file__).resolve().parents[2]
TASK26 = load_tasks()[26].ground_truth
SERVOS = list(load_robot("coco").servos.names)


def _summary_counts(path: Path) -> dict[str, int]:
    """Messages per topic from the MCAP summary, through the ``mcap`` package's own reader."""
    with open(path, "rb") as f:
        s = make_reader(f).get_summary()
    assert s is not None and s.statistics is not None
    return {s.channels[c].topic: n for c, n in s.statistics.channel_message_counts.items()}


def test_task26_mcap_has_every_channel_on_the_board_clock(tmp_path: Path) -> None:
    run = run_e2e(TASK26, tmp_path, task_label="task 26")
    counts = _summary_counts(tmp_path / "run.mcap")
    tel = run.telemetry[0]
    mcap = McapRun(tmp_path / "run.mcap")
    states = list(mcap.messages(["/joint_states"]))
    # one joint state, one transform set and one decoded telemetry per report the host took in
    assert counts["/joint_states"] == counts["/tf"] == counts["/telemetry"] == len(states)
    assert len(states) >= 0.9 * len(tel)  # the host takes in the board's reports (lockstep: all but the last few)
    assert [j["name"] for j in states[0].value["joints"]] == SERVOS
    # stamps are board time: the first report the board logged (its own log) is where the MCAP starts
    board_us = {round(t * 1e6) for t in tel}
    assert all(m.log_time_ns // 1000 in board_us for m in states)
    # targets: one per servo frame sent, stamped at its apply time; the host's frame log agrees
    sent = [m for _, _, m in read_host_to_board(tmp_path / "host_frames.jsonl") if type(m).__name__ == "ServoFrame"]
    assert counts["/joint_targets"] == len(sent)  # the recording starts before the first frame
    assert counts["/link/tx"] >= counts["/joint_targets"] > 0
    assert counts["/scene"] >= 1
    # calls: a start and an end line each, and one Event with the board-measured times of timeline.json
    started = [c for c in run.calls if c.start is not None]
    assert counts["/calls/events"] == len(started)
    assert counts["/calls"] == 2 * len(started)
    events = list(mcap.messages(["/calls/events"]))
    timeline = {c["path"]: c for c in json.loads((tmp_path / "timeline.json").read_text())["calls"]}
    for ev in events:
        meta = {kv["key"]: kv["value"] for kv in ev.value["metadata"]}
        c = timeline[meta["path"]]
        assert meta["outcome"] == c["outcome"] and meta["function"] == c["function"]
        assert abs(ev.log_time_ns / 1e9 - c["end"]) < 1e-6  # logged at its end, when it is known
    # every message in log-time order, in the order the file holds them (a strict player's check)
    with open(tmp_path / "run.mcap", "rb") as f:
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert times == sorted(times)
    # a call's start line at the board time it started (timeline.json), not when the shell released it
    starts = {m.value["message"].split()[1]: m.log_time_ns / 1e9 for m in mcap.messages(["/calls"])
              if m.value["message"].startswith("start ")}
    assert set(starts) == {p for p, c in timeline.items() if c["start"] is not None}
    for path, t in starts.items():
        assert abs(t - timeline[path]["start"]) <= 0.010, path  # one control tick
    # the board's first report (20 ms) is in every channel made from reports
    for topic in ("/joint_states", "/telemetry", "/tf", "/sim_state"):
        assert next(iter(mcap.messages([topic]))).log_time_ns == round(tel[0] * 1e9), topic
    assert mcap.metadata()["run"]["robot"] == "coco"
    with open(tmp_path / "run.mcap", "rb") as f:
        assert [a.name for a in make_reader(f).iter_attachments()] == ["coco.xml"]
    # the robot moved in the 3D view: the torso's transform follows SIM_STATE
    tf = list(mcap.messages(["/tf"]))
    torso = [next(t for t in m.value["transforms"] if t["child_frame_id"] == "torso") for m in (tf[0], tf[-1])]
    assert torso[1]["translation"]["x"] - torso[0]["translation"]["x"] > 0.05  # two strides forward
    print("task 26 run.mcap:", counts)


def test_speech_and_photos_are_recorded_where_the_timeline_has_them(tmp_path: Path) -> None:
    run = run_e2e('Hello there.<capture/><head_act action="nod"/>Nice to meet you.', tmp_path)
    mcap = McapRun(tmp_path / "run.mcap")
    speech = [m.value for m in mcap.messages(["/speech"])]
    spoken = run.find("speak")
    assert [s["text"] for s in speech] == [c.args["text"] for c in spoken]
    for s, c in zip(speech, spoken):
        assert s["start_s"] == pytest.approx(c.start, abs=1e-6) and s["end_s"] == pytest.approx(c.end, abs=1e-6)
        assert s["outcome"] == "done"
    photos = list(mcap.messages(["/camera"]))
    assert len(photos) == 1 and photos[0].value["format"] == "png"
    cap = run.one("capture")
    assert cap.start <= photos[0].log_time_ns / 1e9 <= cap.end + 0.1


def test_fault_run_shows_its_gaps_in_the_summary(tmp_path: Path) -> None:
    run_e2e(TASK26, tmp_path, task_label="task 26", faults="drop=0.03,corrupt=0.01", fault_seed=4)
    summary = json.loads((tmp_path / "summary.json").read_text())
    detected = summary["extra"]["faults"]["host_detected"]
    counts = _summary_counts(tmp_path / "run.mcap")
    assert detected["seq_gaps"] > 0
    assert counts.get("/link/gaps", 0) > 0
    gaps = [m.value for m in McapRun(tmp_path / "run.mcap").messages(["/link/gaps"])]
    assert sum(g["lost"] for g in gaps) == gaps[-1]["lost_total"] <= detected["seq_gaps"]
    assert counts.get("/link/faults", 0) > 0  # the decode errors / re-sent requests, one line each
    print("fault run /link/gaps:", counts["/link/gaps"], "lost", gaps[-1]["lost_total"], "counts", counts)


def test_unwritable_mcap_is_one_line_and_the_run_goes_on(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "run.mcap").mkdir()  # a folder where the file should go: cannot be written, even as root
    with caplog.at_level(logging.WARNING, logger="host.run"):
        run = run_e2e('<head_act action="nod"/>', tmp_path)
    assert run.report.summary.outcome == "done"
    notes = [r.getMessage() for r in caplog.records if "run.mcap" in r.getMessage()]
    assert len(notes) == 1 and "cannot write" in notes[0] and str(tmp_path / "run.mcap") in notes[0]
    assert (tmp_path / "summary.json").exists() and (tmp_path / "run.mcap").is_dir()


@pytest.mark.realtime
def test_killed_run_leaves_an_mcap_readable_up_to_its_last_chunk(tmp_path: Path) -> None:
    """SIGKILL a realtime run once the live view shows board time past 2.5 s: chunks end every FLUSH_S
    board seconds, so the cut file holds at least the first 2 s (synchronised on the run's own messages).
    Realtime, not lockstep: task 26 runs ~6 board-s, so the kill lands while it runs; a lockstep board
    (84x real time since its ticks are batched) can finish the task before the signal is sent (CI saw it)."""
    import anyio

    out = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-m", "host", "run", "--xml", TASK26, "--realtime", "--no-live",
                             "--out", str(out), "--foxglove", "0"], cwd=ROOT, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        port = None
        assert proc.stderr is not None
        for line in proc.stderr:
            m = re.search(r"live view on ws://127\.0\.0\.1:(\d+)", line)
            if m:
                port = int(m.group(1))
                break
        assert port is not None, "the run never started its live view"
        from .test_foxglove_live import joint_state_times

        seen = anyio.run(joint_state_times, port, 2.5, backend="asyncio")
        assert seen[-1] >= 2.5
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    mcap = McapRun(out / "run.mcap")
    assert not mcap.complete
    states = list(mcap.messages(["/joint_states"]))
    assert mcap.truncated is not None and "last complete chunk" in mcap.truncated or "no summary" in (mcap.truncated or "")
    assert states and states[-1].log_time_ns / 1e9 >= 2 * FLUSH_S - 0.02  # the chunk ended at board time 2 s is in
    assert mcap.metadata()["run"]["robot"] == "coco"
    # the command line says what it read and that the file was cut: exit 1, one line
    rc = subprocess.run([sys.executable, "-m", "host", "log", "decode", str(out / "run.mcap"), "--type", "/joint_states"],
                        cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert rc.returncode == 1
    assert len(rc.stdout.splitlines()) == len(states)
    assert rc.stderr.count("\n") == 2 and "its writer did not finish it" in rc.stderr


def test_log_decode_and_replay_read_the_mcap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run_e2e('<head_act action="nod"/><shake_ear/>', tmp_path / "run")
    mcap = tmp_path / "run" / "run.mcap"
    assert cli_main(["log", "decode", str(mcap), "--type", "/calls"]) == 0
    out = capsys.readouterr()
    lines = out.out.splitlines()
    assert lines and all(" /calls " in ln for ln in lines) and "start head_act[0]" in out.out
    # the /link/tx channel is the host's traffic since the recording started: the same messages, seq and order
    tx = list(read_mcap_host_to_board(mcap))
    jsonl = [(s, m) for _, s, m in read_host_to_board(tmp_path / "run" / "host_frames.jsonl")]
    assert [(s, m) for _, s, m in tx] == jsonl[len(jsonl) - len(tx):]
    assert cli_main(["replay", str(mcap), "--out", str(tmp_path / "replay")]) == 0
    summary = json.loads((tmp_path / "replay" / "summary.json").read_text())
    assert summary["base_end_error_mm"] is not None and summary["base_end_error_mm"] < 1.0
    assert McapRun(tmp_path / "replay" / "run.mcap").counts()["/joint_states"] > 0  # the replay records itself too
    bad = tmp_path / "bad.mcap"
    bad.write_text("not an mcap\n")
    assert cli_main(["log", "decode", str(bad)]) == 2
    assert cli_main(["replay", str(bad), "--out", str(tmp_path / "r2")]) == 2  # bad input, as log decode says
    err = capsys.readouterr().err
    assert "not an MCAP file" in err
