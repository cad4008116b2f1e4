"""Bad robot packages: every one is refused with one line naming what and where (file:line), exit 2.

Each case is a working package (generated from the third-party rig, ``support.robot_samples``) with
one edit, quoted in the case. The loader is checked in process for every case; the issue's list
(duplicate servo id, a servo table that disagrees with the MJCF, a pose naming an unknown joint, more
servos than the wire allows, a broken robot module) also through ``ghostshell run --robot`` and the
board (``python -m firmware_sim --robot``) as real subprocesses.
"""

from __future__ import annotations

import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from robots.description import RobotDataError
from robots.generate import generate_package, install_package
from robots.loader import load_robot_dir
from robots.registry import BUILTIN_DIR
from support.robot_samples import cli, line_of, one_line_error, write_rig


def _edit(rel: str, old: str, new: str, count: int = 1) -> Callable[[Path], None]:
    def apply(folder: Path) -> None:
        p = folder / rel
        text = p.read_text()
        assert old in text, (rel, old)
        p.write_text(text.replace(old, new, count))
    return apply


def _append_servos(folder: Path) -> None:
    """33 [[servo]] entries: servo 3's entry repeated with ids 4..33."""
    p = folder / "servos.toml"
    text = p.read_text()
    third = text[text.index("[[servo]]\nid = 3"):]
    p.write_text(text + "".join("\n" + third.replace("id = 3", f"id = {i}").replace('"tilt"', f'"tilt{i}"')
                                for i in range(4, 34)))


def _append(rel: str, text: str) -> Callable[[Path], None]:
    def apply(folder: Path) -> None:
        with open(folder / rel, "a") as f:
            f.write(text)
    return apply


@dataclass(frozen=True)
class Case:
    id: str
    edit: Callable[[Path], None]
    file: str  # the file the message must name
    line: Callable[[Path], int] | None  # its expected line (None: the file alone)
    says: str  # a fragment of the message
    cli: bool = False  # also through run --robot and the board


def _servo_entry(n: int) -> Callable[[Path], int]:
    return lambda folder: line_of(folder / "servos.toml", r"^\[\[servo\]\]", n - 1)


CASES = [
    Case("duplicate servo id: servo 3 says id = 2", _edit("servos.toml", "id = 3", "id = 2"),
         "servos.toml", _servo_entry(3), "duplicate servo id 2", cli=True),
    Case("table disagrees with the MJCF: tilt min_deg = -50 (the MJCF says -45)",
         _edit("servos.toml", "min_deg = -45.0", "min_deg = -50.0"),
         "servos.toml", _servo_entry(3), "joint 'tilt' has range [-45.00, 60.00]", cli=True),
    Case("pose names an unknown joint: home has elbow = 10", _edit("poses.toml", "pan = 28.6479", "elbow = 10.0"),
         "poses.toml", lambda f: line_of(f / "poses.toml", r"^elbow ="), "names 'elbow'", cli=True),
    Case("more servos than the wire allows: 33 [[servo]] entries", _append_servos,
         "servos.toml", _servo_entry(33), "at most 32", cli=True),
    Case("interface module does not import: interface = \"interface\" with a NameError",
         lambda f: (_edit("robot.toml", "# interface = \"interface\"", "interface = \"interface\"")(f),
                    (f / "interface.py").write_text("VOCABULARIES = {'default': {}}\nundefined_name\n")),
         "interface.py", lambda f: 2, "NameError", cli=True),
    Case("interface of the wrong shape: VOCABULARIES = {'default': 3}",
         lambda f: (_edit("robot.toml", "# interface = \"interface\"", "interface = \"interface\"")(f),
                    (f / "interface.py").write_text("VOCABULARIES = {'default': 3}\n")),
         "interface.py", None, "VOCABULARIES must map"),
    Case("behaviours function fails: BEHAVIOURS(robot) looks up a servo the robot lacks",
         lambda f: (_edit("robot.toml", "# behaviours = \"behaviours\"", "behaviours = \"behaviours\"")(f),
                    (f / "behaviours.py").write_text("def BEHAVIOURS(robot):\n    robot.servos.by_name('elbow')\n")),
         "behaviours.py", lambda f: 2, "no servo 'elbow'"),
    Case("table names a joint the MJCF lacks: joint = \"tilt2\"", _edit("servos.toml", 'joint = "tilt"', 'joint = "tilt2"'),
         "servos.toml", _servo_entry(3), "joint 'tilt2' is not in rig.xml"),
    Case("servo drives the wrong actuator: actuator = \"spinner\" (a motor on another joint)",
         _edit("servos.toml", 'actuator = "tilt_servo"', 'actuator = "spinner"'),
         "rig_actuators.xml", lambda f: line_of(f / "rig_actuators.xml", "spinner"), "does not drive joint 'tilt'"),
    Case("pose out of range: home tilt = 90", _edit("poses.toml", "tilt = -17.1887", "tilt = 90.0"),
         "poses.toml", lambda f: line_of(f / "poses.toml", r"^tilt = 90"), "tilt = 90.0 deg outside [-45, 60]"),
    Case("pose list of the wrong length: short = [1.0, 2.0]", _append("poses.toml", "\n[poses]\nshort = [1.0, 2.0]\n"),
         "poses.toml", lambda f: line_of(f / "poses.toml", r"^short ="), "has 2 values; it needs 3"),
    Case("mjcf file missing: mjcf = \"gone.xml\"", _edit("robot.toml", 'mjcf = "rig.xml"', 'mjcf = "gone.xml"'),
         "robot.toml", lambda f: line_of(f / "robot.toml", r"^mjcf ="), "no such file"),
    Case("start pose unknown: start_pose = \"nap\"", _edit("robot.toml", 'start_pose = "home"', 'start_pose = "nap"'),
         "robot.toml", lambda f: line_of(f / "robot.toml", r"^start_pose ="), "'nap' is not a pose"),
    Case("camera not in the MJCF: camera = \"nose\"", _edit("robot.toml", 'camera = "eye"', 'camera = "nose"'),
         "robot.toml", lambda f: line_of(f / "robot.toml", r"^camera ="), "no camera of that name"),
    Case("servo table is not TOML: id = = 3", _edit("servos.toml", "id = 3", "id = = 3"),
         "servos.toml", lambda f: line_of(f / "servos.toml", "id = = 3"), "not valid TOML"),
    Case("wrong TOML type: voices = 7", _edit("robot.toml", "screen = false", "screen = false\nvoices = 7"),
         "robot.toml", None, "wrong type"),
    Case("a range in the servo table upside down: min_deg = 70", _edit("servos.toml", "min_deg = -45.0", "min_deg = 70.0"),
         "servos.toml", _servo_entry(3), "need min_deg < max_deg"),
]


@pytest.fixture(scope="module")
def good_package(tmp_path_factory: pytest.TempPathFactory) -> Path:
    src = write_rig(tmp_path_factory.mktemp("src"))
    return install_package(generate_package("rig", src), tmp_path_factory.mktemp("good"))


def _bad_package(good: Path, robots: Path, case: Case) -> Path:
    folder = robots / "bad"
    shutil.copytree(good, folder)
    case.edit(folder)
    return folder


def _where(folder: Path, case: Case) -> str:
    path = folder / case.file
    return f"{path}:{case.line(folder)}" if case.line else str(path)


def test_the_good_package_loads(good_package: Path) -> None:
    assert load_robot_dir(good_package).servo_count == 3


@pytest.mark.parametrize("case", CASES, ids=[c.id for c in CASES])
def test_loader_refuses_with_file_and_line(case: Case, good_package: Path, tmp_path: Path) -> None:
    folder = _bad_package(good_package, tmp_path, case)
    with pytest.raises(RobotDataError) as e:
        robot = load_robot_dir(folder)
        robot.interface  # noqa: B018 (the modules are imported on first use)
    msg = str(e.value)
    where = _where(folder.resolve(), case)
    assert msg.startswith(where + ":") and re.match(r"^\S+:\d+: " if case.line else r"^\S+: ", msg), (where, msg)
    assert case.says in msg and "\n" not in msg, msg


@pytest.mark.parametrize("case", [c for c in CASES if c.cli], ids=[c.id for c in CASES if c.cli])
def test_run_and_board_refuse_with_one_line(case: Case, good_package: Path, tmp_path: Path) -> None:
    folder = _bad_package(good_package, tmp_path / "robots", case).resolve()
    where = _where(folder, case)
    run = one_line_error(cli("run", "--robot", "bad", "--robots-dir", str(tmp_path / "robots"), "--lockstep",
                             "--no-live", "--out", str(tmp_path / "out"), "--xml", '<pose name="home"/>',
                             data_home=tmp_path))
    assert run.startswith(f"ghostshell run: {where}:") and case.says in run, run
    assert not (tmp_path / "out").exists()  # refused before anything started
    if case.file == "interface.py":
        return  # the board needs only data: it never imports the robot's modules
    board = one_line_error(cli("--link", "pty", "--lockstep", "--robot", "bad", "--robots-dir",
                               str(tmp_path / "robots"), module="firmware_sim", data_home=tmp_path))
    assert board.startswith(f"board: {where}:") and case.says in board, board


@pytest.mark.parametrize("command", [("run", "--xml", '<pose name="home"/>'), ("board", "--link", "pty"),
                                     ("pose", "--link", "/dev/null", "--pose", "home"), ("robots", "show")])
def test_robot_naming_nothing(command: tuple[str, ...], tmp_path: Path) -> None:
    args = [*command, "nobody"] if command == ("robots", "show") else [*command, "--robot", "nobody"]
    line = one_line_error(cli(*args, "--robots-dir", str(tmp_path), data_home=tmp_path))
    builtin = ", ".join(sorted(p.parent.name for p in BUILTIN_DIR.glob("*/robot.toml")))  # the folder holds none
    assert f"no robot 'nobody'; robots: {builtin}" in line and str(tmp_path) in line, line
