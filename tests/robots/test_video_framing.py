"""run.mp4 / ``ghostshell render`` of a robot made from a third-party MJCF (issue 42 item 5): a fixed-base robot
without a floor was a small arm off-centre in a black void. Now it gets a floor and a camera framed on its
bounding box (:mod:`host.run.framing`); a package's own ``[view]`` still wins; floating robots are unchanged.

Frames are rendered offscreen in process, by the video's own worker code (``_init_worker`` + ``_render``), of
the test suite's third-party-style mesh arm (STL meshes through an include, no floor, fixed base).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from robots.generate import generate_package, install_package
from support.mesh_robot import write_mesh_arm
from support.robot_samples import write_crawler, write_rig

video = pytest.importorskip("host.run.video")


@pytest.fixture
def worker() -> Iterator[dict]:  # type: ignore[type-arg]
    video._W.clear()
    yield video._W
    video._W.clear()


def _setup(folder: Path, scene: str = "empty") -> dict:  # type: ignore[type-arg]
    video._init_worker(video.VideoSettings(), scene, str(folder), None)
    if "error" in video._W:
        pytest.skip(f"no offscreen GL here: {video._W['error']}")
    return video._W


def _frame(w: dict, q: np.ndarray | None = None) -> np.ndarray:  # type: ignore[type-arg]
    """The main view of one video frame (without the caption strip), (h, w, 3) uint8."""
    rm = w["rm"]
    pos, quat = rm.base_pose(w["data"])
    joints = np.asarray(rm.robot.servos.neutral if q is None else q, dtype=float)
    raw = video._render((0.0, np.array([*pos, *quat]), joints, "(idle)", "", {}))
    img = np.frombuffer(raw, dtype=np.uint8).reshape(video.HEIGHT, video.WIDTH, 3)
    return img[: video.HEIGHT - video.CAPTION_H]


def _robot_pixels(w: dict) -> np.ndarray:  # type: ignore[type-arg]
    """(row, col) of every pixel the robot's geoms cover, from the video camera (segmentation rendering)."""
    import mujoco

    model, data = w["model"], w["data"]
    seg = mujoco.Renderer(model, height=video.HEIGHT - video.CAPTION_H, width=video.WIDTH)
    try:
        seg.enable_segmentation_rendering()
        seg.update_scene(data, w["cam"])
        ids = seg.render()
    finally:
        seg.close()
    geom = (ids[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (ids[..., 0] >= 0)
    return np.argwhere(geom)


def test_a_fixed_arm_without_a_floor_is_framed_on_a_floor(tmp_path: Path, worker: dict) -> None:  # type: ignore[type-arg]
    folder = write_mesh_arm(tmp_path, segments=8) / "mesh_arm"
    w = _setup(folder)
    framing = w["framing"]
    assert w["framed"] and framing.floor_z is not None  # no [view], no floor in the MJCF
    view = _frame(w)
    dark = float(np.mean(view.max(axis=2) < 24))
    assert dark < 0.35, f"{dark:.0%} of the frame is black"
    px = _robot_pixels(w)
    h, wd = view.shape[:2]
    assert len(px) > 0.015 * h * wd, "the robot is a speck"
    cy, cx = px.mean(axis=0)
    assert abs(cx - wd / 2) < 0.12 * wd and abs(cy - h / 2) < 0.15 * h, (cx, cy)
    (top, left), (bottom, right) = px.min(axis=0), px.max(axis=0)
    assert top > 0 and left > 0 and bottom < h - 1 and right < wd - 1, "the robot is cut off at the frame's edge"
    # the floor is under the robot's lowest point at the neutral pose, and drawn (a light, not black, floor)
    assert framing.floor_z <= framing.box[0][2] + 1e-6
    assert view[-20:, :].mean() > 60


def test_the_camera_holds_a_moved_arm(tmp_path: Path, worker: dict) -> None:  # type: ignore[type-arg]
    """The try: line's move (shoulder_lift half way to its limit) stays in frame: the camera does not follow a base."""
    folder = write_mesh_arm(tmp_path, segments=8) / "mesh_arm"
    w = _setup(folder)
    before = tuple(w["cam"].lookat)
    q = np.zeros(6)
    q[1] = math.radians(50)
    _frame(w, q)
    assert tuple(w["cam"].lookat) == before


def test_a_packages_own_view_wins(tmp_path: Path, worker: dict) -> None:  # type: ignore[type-arg]
    folder = write_mesh_arm(tmp_path, segments=8) / "mesh_arm"
    toml = folder / "robot.toml"
    toml.write_text(toml.read_text() + "\n[view]\ndistance_m = 2.5\nazimuth_deg = 90\nlookat_z = 0.3\n")
    w = _setup(folder)
    assert not w["framed"] and w["cam"].distance == pytest.approx(2.5) and w["cam"].azimuth == pytest.approx(90)
    _frame(w)
    assert w["cam"].lookat[2] == pytest.approx(0.3)
    assert w["framing"].floor_z is not None  # the floor it lacks is still drawn


def test_a_model_with_a_floor_gets_no_second_one(tmp_path: Path, worker: dict) -> None:  # type: ignore[type-arg]
    folder = install_package(generate_package("rig", write_rig(tmp_path / "src")), tmp_path / "robots")
    w = _setup(folder)
    assert w["framed"] and w["framing"].floor_z is None  # the rig's MJCF has a ground plane


def test_a_floating_robot_keeps_the_follow_camera(tmp_path: Path, worker: dict) -> None:  # type: ignore[type-arg]
    folder = install_package(generate_package("crawler", write_crawler(tmp_path / "src")), tmp_path / "robots")
    w = _setup(folder, "floor")
    assert w["framing"] is None and not w["framed"]
    assert w["cam"].distance == pytest.approx(video.VideoSettings().distance_m)
    rm = w["rm"]
    pos, _ = rm.base_pose(w["data"])
    _frame(w)
    assert tuple(w["cam"].lookat[:2]) == pytest.approx(pos[:2])  # it looks at the base


def test_a_floor_box_in_the_world_body_is_the_floor_and_not_framed(tmp_path: Path, worker: dict) -> None:  # type: ignore[type-arg]
    """Scenery on the world body (a 10 m floor box) is a floor: none drawn, and the camera frames the arm, not it."""
    write_mesh_arm(tmp_path, segments=8)
    mjcf = tmp_path / "mjcf" / "arm.xml"
    mjcf.write_text(mjcf.read_text().replace('<light pos="0 0 2"/>', '<light pos="0 0 2"/>\n    <geom type="box" '
                                             'size="5 5 0.01" pos="0 0 -0.05" rgba="0.5 0.5 0.5 1"/>'))
    folder = install_package(generate_package("boxed", mjcf), tmp_path / "boxed")
    w = _setup(folder)
    assert w["framed"] and w["framing"].floor_z is None
    assert w["framing"].distance < 1.5  # the arm's ~0.5 m, not the 10 m box
