"""``ghostshell log decode run.mcap`` prints a big message as one short summary line (schema, payload bytes,
element counts), not its content: a mesh robot's ``/scene`` printed whole was two lines of 59 MB and took
10.7 s. A real RunLog writes the MCAP (the mesh arm of tests/support, its meshes as STL models); the
command's own function reads it back."""

from __future__ import annotations

import io
import re
from pathlib import Path

import pytest

import host.commands.log as log_cmd
from host.run.mcap_log import RunLog
from protocol.messages import FaultFlags, SimState, Telemetry
from robots.description import Robot
from robots.registry import load_robot
from tests.support.mesh_robot import write_mesh_arm


def _record(path: Path, robot: Robot) -> Path:
    n = robot.servo_count
    run_log = RunLog.create(path, robot)
    for k in range(3):
        t = k * 20_000
        run_log.on_message(Telemetry(t, (0.1,) * n, (0.0,) * n, (0.0,) * n, (0.0, 0.0, 0.0), FaultFlags.NONE,
                                     0, 0, 0, 0, 0))
        run_log.on_message(SimState(t, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)))
    run_log.close()
    return path


def _decode(path: Path) -> tuple[int, list[str], str]:
    out, err = io.StringIO(), io.StringIO()
    code = log_cmd.decode_mcap_file(str(path), out, err)
    return code, out.getvalue().splitlines(), err.getvalue()


def test_a_mesh_robots_scene_is_one_short_summary_line(tmp_path: Path) -> None:
    robot = load_robot("mesh_arm", write_mesh_arm(tmp_path / "arm"))  # 13 meshes, ~100 000 triangles
    code, lines, err = _decode(_record(tmp_path / "run.mcap", robot))
    assert code == 0, err
    scene = [ln for ln in lines if " /scene " in ln]
    assert len(scene) == 1
    m = re.search(r"<foxglove\.SceneUpdate: (\d+) B; (.*)>$", scene[0])
    assert m is not None, scene[0][:300]
    assert int(m.group(1)) > log_cmd.SUMMARISE_OVER_BYTES
    counts = dict((k, int(v)) for k, v in (part.rsplit(" ", 1) for part in m.group(2).split(", ")))
    assert counts["entities"] == 7 and counts["models"] == 13
    assert max(len(ln) for ln in lines) <= log_cmd.MAX_LINE_CHARS  # every other line printed in full, short
    assert sum(" /joint_states " in ln for ln in lines) == 3


def test_a_line_over_the_limit_is_summarised_with_its_list_counts(tmp_path: Path,
                                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    path = _record(tmp_path / "run.mcap", load_robot("coco"))
    code, lines, _ = _decode(path)
    scene = next(ln for ln in lines if " /scene " in ln)
    assert code == 0 and '"entities":[' in scene  # CoCo's scene (primitives, a few KB): printed in full
    monkeypatch.setattr(log_cmd, "MAX_LINE_CHARS", 200)
    code, lines, _ = _decode(path)
    scene = next(ln for ln in lines if " /scene " in ln)
    assert code == 0 and re.search(r"<foxglove\.SceneUpdate: \d+ B; entities \d+, cubes \d+", scene), scene
    assert all(len(ln) < 400 for ln in lines)
