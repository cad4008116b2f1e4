"""The desk arm through the commands a user types: ``ghostshell eval --robot arm`` with the scripted
ground truths scores 1.0, ``ghostshell demo --robot arm`` picks a cube while it talks, and its
run.mp4 shows the cube move (rendered from the board's frame log and objects log)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np

from host.run.video import HEIGHT, WIDTH, VideoSettings, load_states, render_video
from robots.registry import load_robot

ARM = load_robot("arm")


def _ghostshell(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host.cli", *args], capture_output=True, text=True, timeout=timeout)


def test_eval_with_the_ground_truths_scores_one(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    p = _ghostshell("eval", "--robot", "arm", "--llm", "ground-truth", "--tasks", "all", "--trials", "1",
                    "--out", str(out))
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    summary = json.loads((out / "eval.json").read_text())["summary"]
    assert summary["micro"] == summary["macro"] == 1.0
    assert summary["jobs"] == len(ARM.tasks) and summary["ran_clean"] == len(ARM.tasks) and summary["fell"] == 0
    assert set(summary["per_category"]) == {"atomic", "sequential", "parallel", "sequential_parallel_composite",
                                            "lifecycle_scoped_termination"}


def test_demo_picks_a_cube_while_talking_and_its_video_shows_it(tmp_path: Path) -> None:
    out = tmp_path / "demo"
    p = _ghostshell("demo", "--robot", "arm", "--lockstep", "--no-video", "--out", str(out), "--no-live")
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    assert f"task {ARM.demo_task}" in p.stdout
    calls = json.loads((out / "timeline.json").read_text())["calls"]
    pick = next(c for c in calls if c["function"] == "pick")
    talk = [c for c in calls if c["function"] == "speak"]
    assert all(c["outcome"] == "done" for c in calls)
    assert any(c["start"] < pick["end"] and pick["start"] < c["end"] for c in talk)  # it talks while it picks
    for name in ("timeline.png", "joints.png", "summary.json", "objects.jsonl"):
        assert (out / name).is_file(), name
    # the video's state: the red cube rises with the gripper and ends on the blue one
    states = load_states(out)
    assert states.joints.shape[1] == 6 and len(states.objects) == len(states.t)
    red_z = np.array([o["red_cube"][2] for o in states.objects])
    assert red_z[0] < 0.015 and red_z.max() > 0.06 and abs(red_z[-1] - 0.0375) < 0.003
    path = render_video(out, settings=VideoSettings(fps=5, workers=2))
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = sum(1 for _ in reader)
    assert meta["codec"].startswith("h264") and tuple(meta["size"]) == (WIDTH, HEIGHT)
    span = states.t[-1] - max(states.t[0], json.loads((out / "timeline.json").read_text())["t0"])
    assert abs(frames - (span * 5 + 1)) <= 1
