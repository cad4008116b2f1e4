"""``--scene bottles``: three light bottles in front of CoCo; summary.json counts the toppled ones
from the simulation's ground truth (SIM_STATE objects/toppled)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from e2e.conftest import run_e2e
from robots.coco.scenes import BOTTLE_POSITIONS, build_model, scene_objects, toppled


def test_walking_into_the_bottles_topples_them(tmp_path: Path) -> None:
    run = run_e2e('<run_distance distance="40"/>', tmp_path / "walk", scene="bottles")
    scene = json.loads((tmp_path / "walk" / "summary.json").read_text())["extra"]["scene"]
    assert scene["name"] == "bottles" and scene["objects"] == 3
    assert scene["toppled"] >= 1
    assert run.report.summary.base_end[0] > BOTTLE_POSITIONS[0][0] - 0.1  # it really walked up to them


def test_standing_still_topples_nothing(tmp_path: Path) -> None:
    run_e2e('<head_act action="nod" duration="1"/>', tmp_path / "nod", scene="bottles")
    scene = json.loads((tmp_path / "nod" / "summary.json").read_text())["extra"]["scene"]
    assert scene == {"name": "bottles", "objects": 3, "toppled": 0}


def test_topple_count_from_orientation() -> None:
    model = build_model("bottles")
    objs = scene_objects(model)
    assert [o.name for o in objs] == ["bottle_0", "bottle_1", "bottle_2"]
    q = model.qpos0.copy()
    assert toppled(q, objs) == 0
    a = objs[1].qpos_adr
    q[a + 3: a + 7] = (np.cos(np.pi / 4), np.sin(np.pi / 4), 0, 0)  # 90 deg about x: lying down
    assert toppled(q, objs) == 1
    with pytest.raises(ValueError, match="valid: empty, bottles"):
        build_model("forest")
