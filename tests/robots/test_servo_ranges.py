"""A servo's range from a real MJCF: the joint ``range`` (mechanical stop) within the actuator ``ctrlrange``
(software limit), as :func:`robots.loader.servo_range` decides it for ``robots new`` and the loader alike.

The MJCF is written here the way third-party arm models are (radians, ``ctrlrange`` on every actuator, the
actuators and joints sharing names, no floor). Issue 42 item 5: a ctrlrange 1 deg narrower than its joint
range was refused; now the servo reaches the intersection, with one note.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from robots.description import RobotDataError
from robots.generate import generate_package, install_package
from robots.loader import load_robot_dir, mjcf_notes
from support.robot_samples import line_of

#: (joint, axis, range rad, link length m)
_JOINTS = (("shoulder_pan", "0 0 1", (-1.92, 1.92), 0.05), ("shoulder_lift", "0 1 0", (-1.75, 1.75), 0.11),
           ("elbow_flex", "0 1 0", (-1.69, 1.69), 0.10), ("gripper", "1 0 0", (-0.17, 1.75), 0.04))


def arm_xml(ctrl: dict[str, str] | None = None, joint_attrs: dict[str, str] | None = None) -> str:
    """A 4-joint arm in radians, no floor; ``ctrl``: joint -> the actuator's ctrlrange attribute text (``""``:
    none; default: the joint range 1 deg narrower on both sides); ``joint_attrs``: joint -> its range text."""
    ctrl = ctrl or {}
    joint_attrs = joint_attrs or {}
    body, acts, indent = [], [], "    "
    for name, axis, (lo, hi), length in _JOINTS:
        narrow = f'ctrlrange="{lo + math.radians(1):.6f} {hi - math.radians(1):.6f}"'
        c = ctrl.get(name, narrow)
        jr = joint_attrs.get(name, f'range="{lo} {hi}"')
        body.append(f'{indent}<body name="{name}_link" pos="0 0 0.05">')
        body.append(f'{indent}  <joint name="{name}" axis="{axis}" {jr}/>')
        body.append(f'{indent}  <geom type="capsule" fromto="0 0 0 0 0 {length}" size="0.02" rgba="0.9 0.6 0.2 1"/>')
        acts.append(f'    <position name="{name}" joint="{name}" kp="20" {c}/>')
        indent += "  "
    for _ in _JOINTS:
        indent = indent[:-2]
        body.append(f"{indent}</body>")
    return "\n".join(['<mujoco model="handmade arm">', '  <compiler angle="radian"/>', '  <worldbody>',
                      '    <light pos="0 0 1.5" dir="0 0 -1"/>', *body, '  </worldbody>', '  <actuator>', *acts,
                      '  </actuator>', '</mujoco>', ''])


def write_arm(folder: Path, **kw: dict[str, str]) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "arm.xml"
    path.write_text(arm_xml(**kw))
    return path


def _limits(pkg) -> dict[str, tuple[float, float]]:  # type: ignore[no-untyped-def]
    return {s.joint: (s.min_deg, s.max_deg) for s in pkg.servos}


def test_ctrlrange_narrower_is_the_intersection_with_one_note(tmp_path: Path) -> None:
    pkg = generate_package("handmade", write_arm(tmp_path / "src"))
    for name, _axis, (lo, hi), _len in _JOINTS:
        assert _limits(pkg)[name] == pytest.approx((math.degrees(lo) + 1, math.degrees(hi) - 1), abs=1e-3)
    notes = [n for n in pkg.notes if "ctrlrange" in n]
    assert len(notes) == 1 and notes[0].startswith("ctrlrange narrower than the joint range on 4 servo(s)"), pkg.notes
    assert "elbow_flex [-95.83, 95.83] deg (joint [-96.83, 96.83] deg)" in notes[0]
    robot = load_robot_dir(install_package(pkg, tmp_path / "robots"))  # the loader agrees
    elbow = robot.servos.by_name("elbow_flex")
    assert (math.degrees(elbow.min), math.degrees(elbow.max)) == pytest.approx((-95.83, 95.83), abs=0.01)
    text = (robot.root / "servos.toml").read_text()
    assert "# joint range -96.83..96.83 within actuator ctrlrange -95.83..95.83" in text
    assert mjcf_notes(robot) == notes  # `robots check` says the same, once


def test_ctrlrange_wider_is_clamped_to_the_joint_with_one_note(tmp_path: Path) -> None:
    wide = {name: f'ctrlrange="{lo - 0.5} {hi + 0.5}"' for name, _a, (lo, hi), _l in _JOINTS}
    pkg = generate_package("handmade", write_arm(tmp_path, ctrl=wide))
    for name, _axis, (lo, hi), _len in _JOINTS:
        assert _limits(pkg)[name] == pytest.approx((math.degrees(lo), math.degrees(hi)))
    notes = [n for n in pkg.notes if "ctrlrange" in n]
    assert len(notes) == 1 and notes[0].startswith("ctrlrange wider than the joint range on 4 servo(s), so the servo "
                                                   "range is the joint range"), pkg.notes
    assert "radians" not in notes[0]
    load_robot_dir(install_package(pkg, tmp_path / "robots"))


def test_ctrlrange_in_degrees_with_angle_degree_is_explained(tmp_path: Path) -> None:
    """MuJoCo reads a hinge's ctrlrange in radians whatever ``compiler angle`` says: ``-110 110`` is +-6300 deg."""
    xml = arm_xml(ctrl={"shoulder_pan": 'ctrlrange="-110 110"'})
    xml = xml.replace('angle="radian"', 'angle="degree"').replace('range="-1.92 1.92"', 'range="-110 110"')
    path = tmp_path / "arm.xml"
    path.write_text(xml)
    notes = [n for n in generate_package("handmade", path).notes if "wider" in n]
    assert len(notes) == 1 and "shoulder_pan" in notes[0] and "in radians" in notes[0], notes


def test_actuator_without_ctrlrange_takes_the_joint_range(tmp_path: Path) -> None:
    none = {name: "" for name, *_ in _JOINTS} | {"gripper": 'ctrllimited="false" ctrlrange="0 0"'}
    pkg = generate_package("handmade", write_arm(tmp_path, ctrl=none))
    for name, _axis, (lo, hi), _len in _JOINTS:
        assert _limits(pkg)[name] == pytest.approx((math.degrees(lo), math.degrees(hi)))
    assert not [n for n in pkg.notes if "ctrlrange" in n], pkg.notes


@pytest.mark.parametrize("with_ctrlrange", [False, True])
def test_joint_without_range_is_refused_at_its_line(tmp_path: Path, with_ctrlrange: bool) -> None:
    """No default range: the joint range is the stop MuJoCo enforces; a servo needs one to be safe."""
    ctrl = {} if with_ctrlrange else {"elbow_flex": ""}
    src = write_arm(tmp_path, ctrl=ctrl, joint_attrs={"elbow_flex": ""})
    with pytest.raises(RobotDataError) as e:
        generate_package("handmade", src)
    msg = str(e.value)
    assert msg.startswith(f"{src}:{line_of(src, '<joint name=.elbow_flex.')}: joint 'elbow_flex' (driven by actuator "
                          "'elbow_flex') has no range; give it range=\"lo hi\""), msg
    hint = "; its actuator 'elbow_flex' has ctrlrange -1.67255 1.67255, so range=\"-1.67255 1.67255\" would do"
    assert (hint in msg) == with_ctrlrange, msg
    assert "\n" not in msg


_HOSTILE = {
    # ctrlrange wholly outside the joint range, above it and below it
    "ctrlrange above": ({"elbow_flex": 'ctrlrange="2 3"'}, {}, "actuator", "lies outside joint 'elbow_flex'"),
    "ctrlrange below": ({"elbow_flex": 'ctrlrange="-3 -2"'}, {}, "actuator", "lies outside joint 'elbow_flex'"),
    "inverted ctrlrange": ({"elbow_flex": 'ctrlrange="1 -1"'}, {}, "actuator", "ctrlrange 1 -1 is inverted"),
    # NaN: refused before MuJoCo compiles it (MuJoCo would print a warning line of its own, and take no range)
    "NaN ctrlrange": ({"elbow_flex": 'ctrlrange="nan 1"'}, {}, "actuator", "position 'elbow_flex' ctrlrange=\"nan 1\" "
                      "holds NaN"),
    "inverted joint range": ({}, {"elbow_flex": 'range="1.69 -1.69"'}, "joint", "range 1.69 -1.69 is inverted"),
    "NaN joint range": ({}, {"elbow_flex": 'range="nan 1"'}, "joint", "joint 'elbow_flex' range=\"nan 1\" holds NaN"),
    "infinite joint range": ({}, {"elbow_flex": 'range="-inf inf"'}, "joint",
                             "range -inf inf is not a pair of finite numbers"),
    "empty joint range": ({}, {"elbow_flex": 'range="0.5 0.5"'}, "joint", "range 0.5 0.5 is empty"),
    "ctrllimited without ctrlrange": ({"elbow_flex": 'ctrllimited="true"'}, {}, "actuator",
                                      "MuJoCo cannot compile it: Error: invalid control range"),
}


@pytest.mark.parametrize("case", list(_HOSTILE))
def test_hostile_ranges_are_one_line_at_file_line(tmp_path: Path, case: str) -> None:
    ctrl, joints, where, says = _HOSTILE[case]
    src = write_arm(tmp_path, ctrl=ctrl, joint_attrs=joints)
    with pytest.raises(RobotDataError) as e:
        generate_package("handmade", src)
    msg = str(e.value)
    pattern = "<position name=.elbow_flex." if where == "actuator" else "<joint name=.elbow_flex."
    assert msg.startswith(f"{src}:{line_of(src, pattern)}: "), msg
    assert says in msg and "\n" not in msg and "Error:" not in msg.split("MuJoCo")[0], msg


def test_the_loader_checks_the_table_against_the_reachable_range(tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    folder = install_package(generate_package("handmade", write_arm(tmp_path / "src")), tmp_path / "robots")
    assert capsys.readouterr().err == ""  # a generated package has nothing to say when it loads
    servos = folder / "servos.toml"
    text = servos.read_text()
    # a table written with the joint range (before ctrlranges counted) still loads, with one note, once
    joint_range = re.sub(r"min_deg = -95\.8\d+", "min_deg = -96.8322", re.sub(r"max_deg = 95\.8\d+", "max_deg = 96.8322", text))
    servos.write_text(joint_range)
    robot = load_robot_dir(folder)
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"note: robot handmade: {servos}: the servo table keeps the joint "
                                               "range where the actuator's ctrlrange is narrower"), err
    assert "elbow_flex [-96.83, 96.83] (reachable [-95.83, 95.83])" in err[0]
    load_robot_dir(folder)
    assert capsys.readouterr().err == ""  # the pass is recorded: the next load (command) checks and says nothing
    table_note = [n for n in mjcf_notes(robot) if n.startswith("the servo table keeps the joint range")]
    assert len(table_note) == 1 and "elbow_flex [-96.83, 96.83] deg (reachable [-95.83, 95.83] deg)" in table_note[0]
    # any other range is refused, naming both places
    servos.write_text(re.sub(r"max_deg = 96\.8322", "max_deg = 90.0", joint_range, count=1))
    with pytest.raises(RobotDataError) as e:
        load_robot_dir(folder)
    assert "servo elbow_flex: the table says [-96.83, 90.00] deg but it reaches [-95.83, 95.83] deg" in str(e.value)
    assert "ctrlrange" in str(e.value)


# --- joint_move's deg: the named joint's own range, one line -------------------------------------------------


@pytest.fixture
def joints_registry(tmp_path: Path):  # type: ignore[no-untyped-def]
    from host.shell.registry import Registry
    from host.shell.types import Module
    from robots.generic import generic_module

    robot = load_robot_dir(install_package(generate_package("handmade", write_arm(tmp_path / "src")), tmp_path / "r"))
    return robot, Registry([Module.interface_only("joints", generic_module(robot))])


@pytest.mark.parametrize("joint, deg, own", [
    ("elbow_flex", "500", "[-95.83, 95.83]"),  # outside every joint's range
    ("elbow_flex", "100", "[-95.83, 95.83]"),  # inside the widest (shoulder_pan's, -109..109) but not its own
    ("gripper", "-20", "[-8.74, 99.27]"),
])
def test_joint_move_out_of_range_names_the_joints_own_range(joints_registry, joint: str, deg: str,  # type: ignore[no-untyped-def]
                                                            own: str) -> None:
    from host.shell.mapper import OutOfRange, map_element

    _robot, reg = joints_registry
    with pytest.raises(OutOfRange) as e:
        map_element(reg, "joint_move", {"joint": joint, "deg": deg})
    assert str(e.value) == f"<joint_move> deg={deg!r} is out of range {own} for joint {joint}"


def test_joint_move_inside_its_range_maps_and_the_behaviour_says_the_same(joints_registry) -> None:  # type: ignore[no-untyped-def]
    from host.shell.mapper import map_element

    robot, reg = joints_registry
    assert map_element(reg, "joint_move", {"joint": "elbow_flex", "deg": "95"}).args == {"joint": "elbow_flex",
                                                                                          "deg": 95.0}
    with pytest.raises(ValueError) as e:  # the behaviour, called from Python, refuses with the same line
        robot.behaviours["joint_move"](np.zeros(robot.servo_count), joint="elbow_flex", deg=100.0)
    assert str(e.value) == "<joint_move> deg=100 is out of range [-95.83, 95.83] for joint elbow_flex"
