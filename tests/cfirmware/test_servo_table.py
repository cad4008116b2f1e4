"""The C servo table comes from a Robot: any robot's table generates and compiles (here a 6-servo
robot derived from CoCo's data, as a 6-servo arm would be), with its name, count and table hash."""

from __future__ import annotations

import dataclasses
import re

import pytest

from firmware_sim.cfirmware.build import build
from firmware_sim.cfirmware.servo_table import servo_table_c, servo_table_h
from robots.description import ServoTable
from robots.registry import load_robot


def _six():
    coco = load_robot("coco")
    model = dataclasses.replace(coco.servos.model, stall_torque=1.5)
    table = ServoTable(coco.servos.servos[:6], model)
    poses = {k: v[:6] for k, v in coco.poses.items()}
    return dataclasses.replace(coco, name="six", servos=table, poses=poses)


def test_six_servo_robot_generates_and_builds() -> None:
    six = _six()
    h, c = servo_table_h(six), servo_table_c(six)
    assert '#define GS_ROBOT_NAME "six"' in h and "#define GS_SERVO_COUNT 6u" in h
    assert f"#define GS_SERVO_TABLE_HASH {six.servos.hash:#010x}u" in h
    rows = re.findall(r"^\s+\{\d+, \"", c, flags=re.M)
    assert len(rows) == 6
    assert ", 1500}," in c  # the table's stall torque is the load's full scale (mN*m)
    assert build("native", six).is_file()


def test_ids_must_be_one_to_n() -> None:
    six = _six()
    servos = list(six.servos.servos)
    servos[0] = dataclasses.replace(servos[0], id=9)
    bad = dataclasses.replace(six, servos=ServoTable(tuple(servos), six.servos.model))
    with pytest.raises(ValueError, match="1..N"):
        servo_table_h(bad)
