"""The desk arm through the commands a user types: ``ghostshell eval --robot arm`` with the scripted
ground truths scores 1.0 (two tasks, run on lockstep boards: a composite one with the wrist camera and
a scoped one), ``ghostshell demo --robot arm`` picks a cube while it talks, and its run.mp4 shows the
cube move (rendered from the board's frame log and objects log). All 15 tasks under eval is a
measurement (``ghostshell eval --robot arm --llm ground-truth``), not a test: it takes minutes."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from host.run.video import HEIGHT, WIDTH, VideoSettings, load_states, render_video
from robots.registry import load_robot

ARM = load_robot("arm")


def _ghostshell(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "host.cli", *args], capture_output=True, text=True, timeout=timeout)


def test_eval_with_the_ground_truths_scores_one(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    p = _ghostshell("eval", "--robot", "arm", "--llm", "ground-truth", "--tasks", "11,15", "--trials", "1",
                    "--workers", "2", "--out", str(out), "--quiet")
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    summary = json.loads((out / "eval.json").read_text())["summary"]
    assert summary["micro"] == summary["macro"] == 1.0
    assert summary["jobs"] == 2 and summary["ran_clean"] == 2 and summary["fell"] == 0
    assert set(summary["per_category"]) == {"sequential_parallel_composite", "lifecycle_scoped_termination"}


@pytest.fixture(scope="module")
def demo_out(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``ghostshell demo --robot arm --lockstep --no-video``'s output folder (run once for the module)."""
    out = tmp_path_factory.mktemp("arm_demo") / "demo"
    p = _ghostshell("demo", "--robot", "arm", "--lockstep", "--no-video", "--out", str(out), "--no-live")
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    assert f"task {ARM.demo_task}" in p.stdout
    return out


def test_demo_picks_a_cube_while_talking(demo_out: Path) -> None:
    calls = json.loads((demo_out / "timeline.json").read_text())["calls"]
    pick = next(c for c in calls if c["function"] == "pick")
    talk = [c for c in calls if c["function"] == "speak"]
    assert all(c["outcome"] == "done" for c in calls)
    assert any(c["start"] < pick["end"] and pick["start"] < c["end"] for c in talk)  # it talks while it picks
    for name in ("timeline.png", "joints.png", "summary.json", "objects.jsonl"):
        assert (demo_out / name).is_file(), name


def test_demo_video_shows_the_cube_move(demo_out: Path) -> None:
    # the video's state: the red cube rises with the gripper and ends on the blue one
    states = load_states(demo_out)
    assert states.joints.shape[1] == 6 and len(states.objects) == len(states.t)
    red_z = np.array([o["red_cube"][2] for o in states.objects])
    assert red_z[0] < 0.015 and red_z.max() > 0.06 and abs(red_z[-1] - 0.0375) < 0.003
    fps = 3  # few frames: the render is checked, not its smoothness
    path = render_video(demo_out, settings=VideoSettings(fps=fps, workers=2))
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = sum(1 for _ in reader)
    assert meta["codec"].startswith("h264") and tuple(meta["size"]) == (WIDTH, HEIGHT)
    span = states.t[-1] - max(states.t[0], json.loads((demo_out / "timeline.json").read_text())["t0"])
    assert abs(frames - (span * fps + 1)) <= 1
