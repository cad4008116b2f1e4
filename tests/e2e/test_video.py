"""run.mp4 from a finished lockstep run: rendered from the board's frame log, H.264, the right length."""

from __future__ import annotations

import imageio_ffmpeg
import pytest

from host.cli import main as cli_main
from host.run.video import HEIGHT, WIDTH, VideoError, VideoSettings, caption_at, load_states, render_video

from .conftest import run_e2e


def test_video_of_a_run(tmp_path) -> None:
    run = run_e2e('<head_act action="nod"/>Hello.', tmp_path, settle_s=0.2)
    states = load_states(run.out)
    assert states.joints.shape[1] == 12 and states.base.shape[1] == 7 and len(states.t) > 20
    path = render_video(run.out, settings=VideoSettings(fps=10, workers=1))
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = sum(1 for _ in reader)
    assert meta["codec"].startswith("h264") and tuple(meta["size"]) == (WIDTH, HEIGHT)
    span = states.t[-1] - max(states.t[0], run.t0)
    assert abs(frames - (span * 10 + 1)) <= 1


def test_caption_shows_active_calls_and_the_sentence() -> None:
    from host.run.video import _Call

    calls = [_Call("head", "head_act(action=nod)", 1.0, 1.6, None), _Call("speech", "speak", 0.5, 2.0, "Hello."),
             _Call("face", "face_emo(emo=smile)", 1.5, 3.0, None)]
    assert caption_at(calls, 1.55) == ("head: head_act(action=nod)   face: face_emo(emo=smile)", "Hello.")
    assert caption_at(calls, 5.0) == ("(idle)", "")


def test_render_without_a_frame_log_says_why(tmp_path, capsys) -> None:
    with pytest.raises(VideoError, match="board_frames.jsonl"):
        render_video(tmp_path)
    assert cli_main(["render", str(tmp_path)]) == 2  # nothing to render there: bad input
    assert "board_frames.jsonl" in capsys.readouterr().err
