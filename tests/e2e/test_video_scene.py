"""The video of a ``--scene bottles`` run is rendered with the run's scene (the bottles are in the model)."""

from __future__ import annotations

from pathlib import Path

import pytest

from host.cli import main as cli_main
from host.run import video
from host.run.video import VideoError, VideoSettings, run_scene


def test_video_model_of_a_bottles_run_has_the_bottles(tmp_path: Path) -> None:
    out = tmp_path / "r"
    assert cli_main(["run", "--xml", '<head_act action="nod"/>', "--scene", "bottles", "--lockstep", "--no-live",
                     "--out", str(out)]) == 0
    assert run_scene(out) == "bottles"
    assert run_scene(tmp_path) == "empty"  # no summary.json: the robot alone
    try:
        video._init_worker(VideoSettings(), run_scene(out))
    except VideoError as e:  # no offscreen GL here
        pytest.skip(str(e))
    try:
        model = video._W["model"]
        bottles = [model.body(i).name for i in range(model.nbody) if model.body(i).name.startswith("bottle_")]
        assert len(bottles) >= 1
    finally:
        for r in ("main", "head"):
            video._W[r].close()
        video._W.clear()
