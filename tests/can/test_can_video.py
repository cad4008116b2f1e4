"""run.mp4 for a CAN run: the state comes from the candump capture (TELEMETRY + SIM_STATE over ISO-TP)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from host.cli import main as cli_main
from host.run.video import HEIGHT, WIDTH, VideoError, load_states, render_video

pytestmark = pytest.mark.timeout(180)


@pytest.mark.slow
def test_run_video_over_slcan(tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "host.cli", "run", "--task", "1", "--link", "can:slcan:pty",
                        "--lockstep", "--video", "--out", str(tmp_path)], capture_output=True, text=True, timeout=150)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert not (tmp_path / "board_frames.jsonl").exists() and (tmp_path / "board_frames.log").exists()
    assert "video:" in r.stdout and (tmp_path / "run.mp4").exists(), r.stdout[-1500:] + r.stderr[-1500:]

    states = load_states(tmp_path)
    s = json.loads((tmp_path / "summary.json").read_text())
    # 50 Hz reports: every TELEMETRY sample is kept, each paired with the latest SIM_STATE
    assert len(states.t) > 0.9 * 50 * (states.t[-1] - states.t[0])
    assert np.all(np.diff(states.t) > 0) and states.joints.shape[1] == 12 and states.base.shape[1] == 7
    assert np.allclose(states.base[-1, :2], s["base_end"][:2], atol=1e-3)  # the run's own final ground truth
    assert np.ptp(states.joints, axis=0).max() > 0.05  # the call moved a servo, and the video shows it

    reader = imageio_ffmpeg.read_frames(str(tmp_path / "run.mp4"))
    meta = next(reader)
    frames = [np.frombuffer(f, np.uint8) for f in reader]
    assert meta["codec"].startswith("h264") and tuple(meta["size"]) == (WIDTH, HEIGHT)
    t0 = json.loads((tmp_path / "timeline.json").read_text()).get("t0") or 0.0
    span = states.t[-1] - max(states.t[0], t0)
    assert abs(len(frames) - (span * 25 + 1)) <= 1
    assert any(not np.array_equal(frames[0], f) for f in frames[1:])  # it is not a still picture


def test_render_without_any_frame_log_names_both(tmp_path: Path, capsys) -> None:
    with pytest.raises(VideoError, match="board_frames.log"):
        render_video(tmp_path)
    assert cli_main(["render", str(tmp_path)]) == 2  # nothing to render there: bad input (the exit-code table)


def test_a_can_log_without_reports_says_so(tmp_path: Path) -> None:
    (tmp_path / "board_frames.log").write_text("(0.000000) vcan0 081#0000000000000000\n")
    with pytest.raises(VideoError, match="no TELEMETRY/SIM_STATE"):
        load_states(tmp_path)
