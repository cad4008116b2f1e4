"""robots.generate: a robot package from one third-party MJCF (the rules in its docstring), in process."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import mujoco
import pytest

from robots.description import MAX_WIRE_SERVOS, RobotDataError
from robots.generate import DEFAULT_MAX_SPEED_DPS, generate_package, install_package
from robots.loader import load_robot_dir
from support.robot_samples import RIG_ACTUATORS_XML, RIG_XML, line_of, write_crawler, write_rig


def _refusal(mjcf: Path, name: str = "rig") -> str:
    with pytest.raises(RobotDataError) as e:
        generate_package(name, mjcf)
    return str(e.value)


def test_rig_servos_poses_and_files(tmp_path: Path) -> None:
    src = write_rig(tmp_path / "src")
    pkg = generate_package("rig", src)
    assert [(s.id, s.joint, s.actuator, s.kind) for s in pkg.servos] == [
        (1, "rail", "rail_servo", "slide"), (2, "pan", "pan_servo", "hinge"), (3, "tilt", "tilt_servo", "hinge")]
    rail, pan, tilt = pkg.servos
    assert (rail.min_deg, rail.max_deg) == pytest.approx((math.degrees(-0.1), math.degrees(0.15)))  # metres x 180/pi
    assert (pan.min_deg, pan.max_deg, tilt.min_deg, tilt.max_deg) == pytest.approx((-120, 120, -45, 60))
    assert [s.neutral_deg for s in pkg.servos] == [0.0, 0.0, 0.0]
    # poses: zero, and home from the MJCF's keyframe (qpos in radians / metres)
    assert pkg.poses["zero"] == (0.0, 0.0, 0.0)
    assert pkg.poses["home"] == pytest.approx((math.degrees(0.05), math.degrees(0.5), math.degrees(-0.3)))
    assert not pkg.floating and pkg.camera == "eye"
    assert any("spinner" in n and "not a position actuator" in n for n in pkg.notes)  # the motor is no servo
    assert sorted(pkg.copies) == ["assets/plate.obj", "rig.xml", "rig_actuators.xml"]
    assert pkg.mjcf == "rig.xml"

    folder = install_package(pkg, tmp_path / "robots")
    robot = load_robot_dir(folder)
    assert robot.name == "rig" and robot.servo_count == 3 and not robot.builtin
    assert robot.servos.max_speeds == pytest.approx([math.radians(DEFAULT_MAX_SPEED_DPS)] * 3)
    assert (robot.start_pose, robot.rest_pose, robot.safe_pose) == ("home", "home", "home")
    assert robot.channels == {} and robot.peripherals.camera == "eye" and not robot.peripherals.speaker
    assert set(robot.interface.stubs()) == {"pose", "joint_move"}
    assert set(robot.behaviours) == {"pose", "joint_move"}
    assert robot.model().model.nu == 4  # the copied MJCF compiles with its include and mesh


def test_max_speed_and_title(tmp_path: Path) -> None:
    pkg = generate_package("rig2", write_rig(tmp_path), max_speed_dps=90, title="My rig")
    robot = load_robot_dir(install_package(pkg, tmp_path / "robots"))
    assert robot.title == "My rig"
    assert robot.servos.max_speeds == pytest.approx([math.radians(90)] * 3)
    with pytest.raises(RobotDataError, match="max-speed-dps"):
        generate_package("rig3", tmp_path / "rig.xml", max_speed_dps=0)


def test_floating_base_spawn_height_and_floor(tmp_path: Path) -> None:
    pkg = generate_package("crawler", write_crawler(tmp_path / "src"))
    assert pkg.floating and pkg.camera == "mast_cam"
    robot = load_robot_dir(install_package(pkg, tmp_path / "robots"))
    assert robot.base.floating and robot.base.feet == ()
    assert robot.base.spawn_height == pytest.approx(0.03 + 0.005)  # the chassis box's half height + clearance
    assert robot.default_scene == "floor"  # the MJCF has no ground plane
    cm = robot.model()
    data = cm.new_data()
    cm.place_on_floor(data, robot.servos.neutral)
    for _ in range(500):  # 1 s: it settles on the floor, upright
        mujoco.mj_step(cm.model, data)
    assert 0.025 < data.qpos[cm.root_qpos + 2] < 0.035


def test_other_keyframes_become_poses_clamped(tmp_path: Path) -> None:
    xml = RIG_XML.replace('<key name="home" qpos="0.05 0.5 -0.3 0"/>',
                          '<key name="home" qpos="0.05 0.5 -0.3 0"/>\n    <key name="look_up" qpos="0 0 2.0 0"/>')
    pkg = generate_package("rig", write_rig(tmp_path, xml))
    assert pkg.poses["look_up"] == pytest.approx((0.0, 0.0, 60.0))  # 2 rad clamped to the tilt's 60 deg
    assert any("look_up" in n and "clamped" in n for n in pkg.notes)


def test_home_without_keyframe_is_neutral(tmp_path: Path) -> None:
    xml = RIG_XML.replace('<key name="home" qpos="0.05 0.5 -0.3 0"/>', '<key name="other" qpos="0 0 0 0"/>')
    xml = xml.replace('range="-45 60"', 'range="10 60"')  # 0 outside: the neutral is clamped to 10
    pkg = generate_package("rig", write_rig(tmp_path, xml))
    assert pkg.poses["home"] == pytest.approx((0.0, 0.0, 10.0)) and pkg.poses["zero"] == pkg.poses["home"]


# --- refusals: one message naming file:line -----------------------------------------------------------


def test_no_position_actuator(tmp_path: Path) -> None:
    src = write_rig(tmp_path, actuators='<mujoco>\n  <actuator>\n    <motor name="m" joint="pan"/>\n'
                                         '    <velocity name="v" joint="tilt" kv="1"/>\n  </actuator>\n</mujoco>\n')
    msg = _refusal(src)
    assert msg.startswith(f"{tmp_path / 'rig_actuators.xml'}:3: no position actuator"), msg  # in the included file
    assert "motor 'm'" in msg and "velocity 'v'" in msg


def test_no_actuators_at_all(tmp_path: Path) -> None:
    src = write_rig(tmp_path, RIG_XML.replace('<include file="rig_actuators.xml"/>', ""))
    msg = _refusal(src)
    assert msg.startswith(f"{src}:1: no position actuator") and "no actuators" in msg, msg


def test_joint_without_range(tmp_path: Path) -> None:
    src = write_rig(tmp_path, RIG_XML.replace(' range="-45 60"', ""))
    msg = _refusal(src)
    line = line_of(src, r'<joint name="tilt"')
    assert msg.startswith(f"{src}:{line}: joint 'tilt'") and "has no range" in msg, msg


def test_ctrlrange_narrower_than_joint_narrows_the_servo(tmp_path: Path) -> None:
    """The joint range is the mechanical stop, the ctrlrange the software limit: the servo reaches the intersection
    (tests/robots/test_servo_ranges.py has the rest of the rules)."""
    src = write_rig(tmp_path, actuators=RIG_ACTUATORS_XML.replace('class="servo"/>', 'class="servo" ctrlrange="-0.5 0.5"/>'))
    pkg = generate_package("rig", src)
    tilt = pkg.servos[2]
    assert (tilt.min_deg, tilt.max_deg) == pytest.approx((math.degrees(-0.5), math.degrees(0.5)))  # joint: -45..60
    assert sum("ctrlrange narrower" in n for n in pkg.notes) == 1


def test_unnamed_position_actuator(tmp_path: Path) -> None:
    src = write_rig(tmp_path, actuators=RIG_ACTUATORS_XML.replace('name="tilt_servo" ', ""))
    msg = _refusal(src)
    acts = tmp_path / "rig_actuators.xml"
    assert msg.startswith(f"{acts}:{line_of(acts, 'joint=.tilt.')}:") and "has no name" in msg, msg


def test_two_servos_on_one_joint(tmp_path: Path) -> None:
    src = write_rig(tmp_path, actuators=RIG_ACTUATORS_XML.replace(
        '<motor name="spinner"', '<position name="pan_again" joint="pan" kp="5"/>\n    <motor name="spinner"'))
    msg = _refusal(src)
    acts = tmp_path / "rig_actuators.xml"
    assert msg.startswith(f"{acts}:{line_of(acts, 'pan_again')}: actuator 'pan_again' drives joint 'pan'"), msg


def test_more_servos_than_the_wire_carries(tmp_path: Path) -> None:
    n = MAX_WIRE_SERVOS + 1
    bodies = "\n".join(f'<body name="b{i}" pos="0 0 {0.1 * i}"><joint name="j{i}" range="-1 1"/><geom size="0.02"/></body>'
                       for i in range(n))
    acts = "\n".join(f'<position name="a{i}" joint="j{i}" kp="5"/>' for i in range(n))
    src = tmp_path / "many.xml"
    src.write_text(f"<mujoco>\n<worldbody>\n{bodies}\n</worldbody>\n<actuator>\n{acts}\n</actuator>\n</mujoco>\n")
    msg = _refusal(src)
    assert msg.startswith(f"{src}:{line_of(src, 'name=.a32.')}: actuator 'a32' would be servo 33"), msg


def test_mjcf_mujoco_cannot_compile(tmp_path: Path) -> None:
    src = write_rig(tmp_path, RIG_XML.replace('joint="rail"', 'joint="nope"').replace("<worldbody>", "<worldbody>"),
                    RIG_ACTUATORS_XML.replace('joint="rail"', 'joint="nope"'))
    msg = _refusal(src)
    acts = tmp_path / "rig_actuators.xml"  # MuJoCo says "line 0" for an included file's element: found by its name
    assert msg.startswith(f"{acts}:{line_of(acts, 'rail_servo')}: MuJoCo cannot compile it:") and "\n" not in msg, msg


def test_bad_names_and_missing_file(tmp_path: Path) -> None:
    src = write_rig(tmp_path)
    for bad in ("Rig", "9rig", "my-rig", "", "a" * 33):
        assert "must match [a-z][a-z0-9_]*" in _refusal(src, bad)
    assert _refusal(tmp_path / "absent.xml") == f"{tmp_path / 'absent.xml'}: no such file"


def test_absolute_asset_path_refused(tmp_path: Path) -> None:
    src = write_rig(tmp_path / "src")
    mesh = (tmp_path / "src" / "assets" / "plate.obj").resolve()
    src.write_text(RIG_XML.replace('file="plate.obj"', f'file="{mesh}"'))
    msg = _refusal(src)
    assert msg.startswith(f"{src}:{line_of(src, '<mesh ')}: mesh file") and "absolute path" in msg, msg


def test_files_above_the_mjcf_keep_their_layout(tmp_path: Path) -> None:
    """meshdir="../meshes": the package puts the model under model/ so the relative path still holds."""
    root = tmp_path / "thirdparty"
    write_rig(root / "xml")
    (root / "meshes").mkdir()
    shutil.move(str(root / "xml" / "assets" / "plate.obj"), root / "meshes" / "plate.obj")
    src = root / "xml" / "rig.xml"
    src.write_text(RIG_XML.replace('meshdir="assets"', 'meshdir="../meshes"'))
    pkg = generate_package("rig", src)
    assert pkg.mjcf == "model/xml/rig.xml"
    assert sorted(pkg.copies) == ["model/meshes/plate.obj", "model/xml/rig.xml", "model/xml/rig_actuators.xml"]
    robot = load_robot_dir(install_package(pkg, tmp_path / "robots"))
    assert robot.mjcf == tmp_path / "robots" / "rig" / "model" / "xml" / "rig.xml"


def test_install_refuses_an_existing_folder_unless_forced(tmp_path: Path) -> None:
    pkg = generate_package("rig", write_rig(tmp_path / "src"))
    robots = tmp_path / "robots"
    folder = install_package(pkg, robots)
    (folder / "mine.txt").write_text("keep")
    with pytest.raises(RobotDataError, match="exists; choose another name or pass --force"):
        install_package(pkg, robots)
    assert (folder / "mine.txt").read_text() == "keep"  # nothing lost
    install_package(pkg, robots, force=True)
    assert not (folder / "mine.txt").exists() and (folder / "robot.toml").is_file()
    assert sorted(p.name for p in robots.iterdir()) == ["rig"]  # no staging folders left behind


def test_a_weak_actuator_is_noted(tmp_path: Path) -> None:
    """tilt with kp 0.05 N*m/rad cannot hold its link level: the static error is noted (not refused)."""
    src = write_rig(tmp_path, actuators=RIG_ACTUATORS_XML.replace(
        '<position name="tilt_servo" joint="tilt" class="servo"/>',
        '<position name="tilt_servo" joint="tilt" class="servo" kp="0.05"/>'))
    pkg = generate_package("rig", src)
    notes = [n for n in pkg.notes if n.startswith("joint 'tilt'")]
    assert len(notes) == 1 and "deg off target" in notes[0] and "kp 0.05" in notes[0], pkg.notes
    assert not any(n.startswith(("joint 'pan'", "joint 'rail'")) for n in pkg.notes)  # a vertical axis / no load
