"""Third-party MJCFs for the robot-package tests (not shaped like the built-in robots) and CLI helpers.

* :func:`write_rig`: a fixed-base camera rig: a linear rail carrying a pan-tilt head (a slide joint and
  two hinges), ``compiler meshdir`` with an OBJ mesh, default classes, the actuators in an
  ``<include>``d file, one ``<general biastype="affine">`` position servo, a ``<motor>`` on a passive
  wheel (not a servo), a ``home`` keyframe and a camera; angles in degrees.
* :func:`write_crawler`: a floating base: a box chassis on a free joint with two flippers and a
  camera mast, no ground plane, angles in radians.
* :func:`cli`: ``python -m host ARGS`` (or any module) as a subprocess with an isolated user data
  folder; :func:`one_line_error` checks the bad-input contract (exit 2, one stderr line, no traceback).
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

__all__ = ["CRAWLER_XML", "RIG_ACTUATORS_XML", "RIG_BEHAVIOURS_PY", "RIG_INTERFACE_PY", "RIG_XML", "add_scan",
           "cli", "line_of", "one_line_error", "write_crawler", "write_rig"]

RIG_XML = """\
<mujoco model="rail camera rig">
  <compiler angle="degree" meshdir="assets" autolimits="true"/>
  <option timestep="0.002" integrator="implicitfast"/>
  <default>
    <default class="servo">
      <joint damping="0.4" armature="0.01"/>
      <position kp="40" kv="1" forcerange="-8 8"/>
    </default>
    <default class="link">
      <geom type="capsule" size="0.02" rgba="0.3 0.4 0.8 1" density="800"/>
    </default>
  </default>
  <asset>
    <mesh name="plate" file="plate.obj"/>
  </asset>
  <worldbody>
    <light pos="0 0 2"/>
    <geom name="ground" type="plane" size="1 1 0.1"/>
    <body name="base" pos="0 0 0.05">
      <geom type="mesh" mesh="plate" rgba="0.2 0.2 0.2 1"/>
      <body name="carriage" pos="0 0 0.02">
        <joint name="rail" type="slide" axis="1 0 0" range="-0.1 0.15" class="servo"/>
        <geom class="link" fromto="0 0 0 0 0 0.08"/>
        <body name="pan_link" pos="0 0 0.1">
          <joint name="pan" axis="0 0 1" range="-120 120" class="servo"/>
          <geom class="link" fromto="0 0 0 0 0 0.05"/>
          <body name="tilt_link" pos="0 0 0.06">
            <joint name="tilt" axis="0 1 0" range="-45 60" class="servo"/>
            <geom class="link" fromto="0 0 0 0.12 0 0"/>
            <camera name="eye" pos="0.13 0 0" xyaxes="0 -1 0 0 0 1"/>
            <body name="wheel" pos="0.12 0 0">
              <joint name="spin" axis="1 0 0"/>
              <geom type="cylinder" size="0.02 0.005" euler="0 90 0" rgba="1 0.5 0 1"/>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
  <contact>
    <exclude body1="base" body2="carriage"/>
  </contact>
  <include file="rig_actuators.xml"/>
  <keyframe>
    <key name="home" qpos="0.05 0.5 -0.3 0"/>
  </keyframe>
</mujoco>
"""

RIG_ACTUATORS_XML = """\
<mujoco>
  <actuator>
    <position name="rail_servo" joint="rail" class="servo" kp="400" kv="20" forcerange="-40 40"/>
    <general name="pan_servo" joint="pan" class="servo" gainprm="40" biastype="affine" biasprm="0 -40 -1"/>
    <position name="tilt_servo" joint="tilt" class="servo"/>
    <motor name="spinner" joint="spin" gear="1"/>
  </actuator>
</mujoco>
"""

_PLATE_OBJ = "".join(f"v {x} {y} {z}\n" for z in (-0.01, 0.01) for x, y in
                     ((-0.05, -0.05), (0.05, -0.05), (0.05, 0.05), (-0.05, 0.05))) + \
    "f 1 2 3\nf 1 3 4\nf 5 6 7\nf 5 7 8\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n"

CRAWLER_XML = """\
<mujoco model="crawler">
  <compiler angle="radian"/>
  <option timestep="0.002"/>
  <default>
    <joint damping="0.2"/>
    <position kp="8" kv="0.2" forcerange="-3 3"/>
    <geom friction="0.8" rgba="0.7 0.6 0.3 1"/>
  </default>
  <worldbody>
    <light pos="0 0 2"/>
    <body name="chassis" pos="0 0 0.3">
      <freejoint name="root"/>
      <geom type="box" size="0.12 0.08 0.03" mass="0.8"/>
      <body name="left_arm" pos="0.12 0.09 0">
        <joint name="left_flip" axis="0 1 0" range="-1.2 1.2"/>
        <geom type="capsule" fromto="0 0 0 0.08 0 0" size="0.012" mass="0.05"/>
      </body>
      <body name="right_arm" pos="0.12 -0.09 0">
        <joint name="right_flip" axis="0 1 0" range="-1.2 1.2"/>
        <geom type="capsule" fromto="0 0 0 0.08 0 0" size="0.012" mass="0.05"/>
      </body>
      <body name="mast" pos="-0.08 0 0.03">
        <joint name="mast_yaw" axis="0 0 1" range="-1.57 1.57"/>
        <geom type="cylinder" size="0.01 0.04" pos="0 0 0.04" mass="0.03"/>
        <camera name="mast_cam" pos="0 0 0.09" xyaxes="0 -1 0 0 0 1"/>
      </body>
    </body>
  </worldbody>
  <actuator>
    <position name="left_flip" joint="left_flip"/>
    <position name="right_flip" joint="right_flip"/>
    <position name="mast_yaw" joint="mast_yaw" kp="4"/>
  </actuator>
</mujoco>
"""


#: docs/guides/robots.md, "Add your robot": a behaviour of the rig (a pan sweep) ...
RIG_BEHAVIOURS_PY = """\
import math

from robots.motion import JointLimits, Track


def BEHAVIOURS(robot):
    limits = JointLimits.of_robot(robot)
    pan = robot.servos.by_name("pan").index

    def scan(start, *, persistent=False, times=1):
        track = Track([pan], start, limits)
        for _ in range(times):
            track.move([math.radians(-60)], 0.8).move([math.radians(60)], 0.8)
        return track.build(hold_end=persistent)

    return {"scan": scan}
"""

#: ... and the stub the LLM sees for it
RIG_INTERFACE_PY = """\
from typing import Annotated

from annotated_types import Interval

from robots.interface import stub


class Head:
    \"\"\"The pan-tilt head.\"\"\"

    @stub("head")
    def scan(self, times: Annotated[int, Interval(ge=1, le=10)] = 1) -> None:
        \"\"\"Sweep the camera from right to left `times` times.\"\"\"


VOCABULARIES = {"default": {"head": Head}}
"""


def add_scan(folder: Path) -> None:
    """Give a generated rig package the robots guide's behaviour, stub and channel."""
    (folder / "behaviours.py").write_text(RIG_BEHAVIOURS_PY)
    (folder / "interface.py").write_text(RIG_INTERFACE_PY)
    toml = folder / "robot.toml"
    text = toml.read_text().replace('# interface = "interface"', 'interface = "interface"')
    text = text.replace('# behaviours = "behaviours"', 'behaviours = "behaviours"')
    toml.write_text(text + '\n[channels.head]\nservos = ["pan", "tilt"]\ndoc = "the pan-tilt head"\n')


def write_rig(folder: Path, xml: str = RIG_XML, actuators: str = RIG_ACTUATORS_XML) -> Path:
    """Write the rig (MJCF, included actuators, the mesh under ``assets/``) into ``folder``; its MJCF path."""
    (folder / "assets").mkdir(parents=True, exist_ok=True)
    (folder / "assets" / "plate.obj").write_text(_PLATE_OBJ)
    (folder / "rig_actuators.xml").write_text(actuators)
    path = folder / "rig.xml"
    path.write_text(xml)
    return path


def write_crawler(folder: Path, xml: str = CRAWLER_XML) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "crawler.xml"
    path.write_text(xml)
    return path


def cli(*args: str, data_home: Path, module: str = "host", timeout: float = 240.0,
        env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    """``python -m MODULE ARGS``; the user data folder (platformdirs) is ``data_home``, no $GHOSTSHELL_ROBOTS."""
    e = {k: v for k, v in os.environ.items() if k != "GHOSTSHELL_ROBOTS"}
    e.update({"XDG_DATA_HOME": str(data_home), "MUJOCO_GL": "egl", **(env or {})})
    return subprocess.run([sys.executable, "-m", module, *args], capture_output=True, text=True, timeout=timeout,
                          env=e, stdin=subprocess.DEVNULL)


def one_line_error(res: subprocess.CompletedProcess[str]) -> str:
    """Assert the bad-input contract (exit 2, exactly one stderr line, no traceback) and return that line."""
    lines = [x for x in res.stderr.splitlines() if x.strip()]
    assert res.returncode == 2, f"exit {res.returncode}\nstdout: {res.stdout}\nstderr: {res.stderr}"
    assert "Traceback" not in res.stderr, res.stderr
    assert len(lines) == 1, res.stderr
    return lines[0]


def line_of(path: Path, pattern: str, occurrence: int = 0) -> int:
    """1-based line of the ``occurrence``-th line of ``path`` matching regex ``pattern`` (for expected file:line)."""
    hits = [n for n, text in enumerate(path.read_text().splitlines(), start=1) if re.search(pattern, text)]
    return hits[occurrence]
