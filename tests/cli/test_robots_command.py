"""``ghostshell robots new|list|show|path`` and a generated robot driven end to end, as real subprocesses.

The done criterion of issue 15 item 4: a robot generated from a third-party MJCF (written here, not in
the repo) runs ``<pose name="home"/>`` and ``<joint_move .../>`` on the emulated board over a real pty
(lockstep MuJoCo) with no code change, and the board's telemetry puts every joint within 3 deg of its
target. Every command gets its own user data folder (``XDG_DATA_HOME``), so no test touches the real one.
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest

from host.link.board_process import start_board
from protocol.framelog import iter_records
from robots.generate import generate_package, install_package
from robots.registry import BUILTIN_DIR
from support.robot_samples import (RIG_ACTUATORS_XML, add_scan, cli, line_of, one_line_error, write_crawler,
                                   write_rig)

TOLERANCE_DEG = 3.0


def _final_positions_deg(out: Path) -> list[float]:
    """Joint positions (deg; a slide joint's metres x 180/pi) in the board's last TELEMETRY."""
    last = None
    with open(out / "board_frames.jsonl", encoding="utf-8") as f:
        for rec in iter_records(f):
            if rec.get("type") == "TELEMETRY" and rec["dir"] == "tx":
                last = rec["fields"]["positions"]
    assert last is not None, "the board sent no telemetry"
    return [math.degrees(v) for v in last]


# --- new / list / show / path -------------------------------------------------------------------------


def test_new_writes_into_the_user_robot_folder_and_list_show_path_see_it(tmp_path: Path) -> None:
    src = write_rig(tmp_path / "thirdparty")
    user_dir = tmp_path / "ghostshell" / "robots"  # platformdirs: $XDG_DATA_HOME/ghostshell/robots

    path = cli("robots", "path", data_home=tmp_path)
    assert path.returncode == 0 and path.stdout.strip() == str(user_dir)

    new = cli("robots", "new", "rig", "--mjcf", str(src), data_home=tmp_path)
    assert new.returncode == 0, new.stderr
    assert "robot rig: 3 servos (1:rail (slide), 2:pan, 3:tilt), poses zero, home, fixed base, camera eye" in new.stdout
    assert f"written to {user_dir / 'rig'}" in new.stdout
    assert "note: skipped actuators (not servos): motor 'spinner'" in new.stderr
    assert sorted(p.name for p in (user_dir / "rig").iterdir()) == [
        "assets", "poses.toml", "rig.xml", "rig_actuators.xml", "robot.toml", "servos.toml"]

    listing = cli("robots", "list", data_home=tmp_path)
    assert listing.returncode == 0, listing.stderr
    rows = {line.split()[0]: line.split() for line in listing.stdout.splitlines()[1:]}
    assert rows["coco"][1:3] == ["12", "built-in"] and rows["coco"][-1] == "default"
    assert rows["rig"][1:4] == ["3", "user", str(user_dir / "rig")]

    show = cli("robots", "show", "rig", data_home=tmp_path)
    assert show.returncode == 0, show.stderr
    assert show.stdout.startswith("rig: rail camera rig (3 servos, user robot)")
    assert "servos: 1:rail[-6..9], 2:pan[-120..120], 3:tilt[-45..60]" in show.stdout
    assert "pose(name: zero|home, duration: float 0..120 = 1.0)  [channel joints]" in show.stdout
    assert "joint_move(joint: rail|pan|tilt, deg: float -120..120, duration: float 0..120 = 1.0)" in show.stdout

    where = cli("robots", "path", "rig", data_home=tmp_path)
    assert where.returncode == 0 and where.stdout.strip() == str(user_dir / "rig")
    assert cli("robots", "path", "coco", data_home=tmp_path).stdout.strip().endswith("/robots/coco")


def test_new_honours_robots_dir_then_the_environment(tmp_path: Path) -> None:
    src = write_rig(tmp_path / "thirdparty")
    env_dir, flag_dir = tmp_path / "env_robots", tmp_path / "flag_robots"
    env = {"GHOSTSHELL_ROBOTS": str(env_dir)}
    assert cli("robots", "new", "a", "--mjcf", str(src), data_home=tmp_path, env=env).returncode == 0
    assert cli("robots", "new", "b", "--mjcf", str(src), "--robots-dir", str(flag_dir), data_home=tmp_path,
               env=env).returncode == 0
    assert (env_dir / "a" / "robot.toml").is_file() and (flag_dir / "b" / "robot.toml").is_file()
    assert cli("robots", "path", data_home=tmp_path, env=env).stdout.strip() == str(env_dir)
    listing = cli("robots", "list", "--robots-dir", str(flag_dir), data_home=tmp_path, env=env).stdout
    builtin = sorted(p.parent.name for p in BUILTIN_DIR.glob("*/robot.toml"))  # coco, arm, ...
    assert [line.split()[0] for line in listing.splitlines()[1:]] == ["b", "a", *builtin]  # search order


def test_list_marks_broken_and_shadowing_packages(tmp_path: Path) -> None:
    robots = tmp_path / "robots"
    folder = install_package(generate_package("rig", write_rig(tmp_path / "src")), robots)
    shutil.copytree(folder, robots / "broken")
    servos = robots / "broken" / "servos.toml"
    servos.write_text(servos.read_text().replace("id = 3", "id = 2"))
    new = cli("robots", "new", "coco", "--mjcf", str(tmp_path / "src" / "rig.xml"), "--robots-dir", str(robots),
              data_home=tmp_path)
    line = one_line_error(new)  # would shadow the built-in coco
    assert line == (f"ghostshell robots: {robots / 'coco'}: a robot 'coco' there would shadow the built-in robot in "
                    f"{Path(__file__).resolve().parents[2] / 'robots' / 'coco'}; choose another name or pass --force")
    assert cli("robots", "new", "coco", "--mjcf", str(tmp_path / "src" / "rig.xml"), "--robots-dir", str(robots),
               "--force", data_home=tmp_path).returncode == 0

    res = cli("robots", "list", "--robots-dir", str(robots), data_home=tmp_path)
    assert res.returncode == 0 and "Traceback" not in res.stderr
    lines = {(ln.split()[0], ln.split()[2]): ln for ln in res.stdout.splitlines()[1:]}
    bad_line = line_of(servos, r"^\[\[servo\]\]", 2)
    assert f"broken: {servos.resolve()}:{bad_line}: duplicate servo id 2" in lines[("broken", "user")]
    assert lines[("broken", "user")].split()[1] == "-"
    assert "shadows " in lines[("coco", "user")] and lines[("coco", "user")].split()[1] == "3"
    assert f"hidden by {robots / 'coco'}" in lines[("coco", "built-in")]


@pytest.mark.parametrize("case", ["no position actuator", "joint without range", "existing folder"])
def test_new_refuses_with_one_line(case: str, tmp_path: Path) -> None:
    robots = tmp_path / "robots"
    if case == "no position actuator":
        src = write_rig(tmp_path / "src", actuators='<mujoco>\n  <actuator>\n    <motor name="m" joint="pan"/>\n'
                                                      "  </actuator>\n</mujoco>\n")
        where = f"{tmp_path / 'src' / 'rig_actuators.xml'}:3"
    elif case == "joint without range":
        src = write_rig(tmp_path / "src", actuators=RIG_ACTUATORS_XML)
        src.write_text(src.read_text().replace(' range="-120 120"', ""))
        where = f"{src}:{line_of(src, '<joint name=.pan.')}"
    else:
        src = write_rig(tmp_path / "src")
        (robots / "rig").mkdir(parents=True)
        where = str(robots / "rig")
    line = one_line_error(cli("robots", "new", "rig", "--mjcf", str(src), "--robots-dir", str(robots),
                              data_home=tmp_path))
    assert line.startswith(f"ghostshell robots: {where}: "), line
    if case != "existing folder":
        assert not (robots / "rig").exists()  # nothing written


# --- host and board started with different robots ---------------------------------------------------


def test_host_and_board_with_different_robots(tmp_path: Path) -> None:
    robots = tmp_path / "robots"
    install_package(generate_package("rig", write_rig(tmp_path / "src")), robots)
    board = start_board(["--lockstep", "--robot", "rig", "--robots-dir", str(robots)], tmp_path / "board.stderr")
    try:
        pose = one_line_error(cli("pose", "--robot", "coco", "--link", board.port, "--pose", "stand",
                                  data_home=tmp_path))
        assert pose.startswith(f"ghostshell pose: the board on {board.port} drives robot 'rig' (3 servos"), pose
        assert "started for 'coco' (12 servos" in pose and "--robot" in pose
        run = cli("run", "--robot", "coco", "--link", board.port, "--lockstep", "--no-live", "--out",
                  str(tmp_path / "run"), "--xml", '<pose name="stand"/>', data_home=tmp_path)
        line = one_line_error(run)
        assert line.startswith("ghostshell run: the board on") and "drives robot 'rig'" in line and "'coco'" in line, line
        # the same board still serves its own robot
        ok = cli("pose", "--robot", "rig", "--robots-dir", str(robots), "--link", board.port, "--pose", "home",
                 data_home=tmp_path)
        assert ok.returncode == 0, ok.stderr
    finally:
        board.stop()


# --- the done criterion: a generated robot end to end ------------------------------------------------


@pytest.mark.parametrize("robot, moves, target", [
    # fixed base: a slide rail and a pan-tilt head; home is the MJCF's keyframe (rail 0.05 m, pan 0.5 rad, tilt -0.3 rad)
    ("rig", '<joint_move joint="pan" deg="30" duration="1"/><joint_move joint="rail" deg="-4" duration="0.5"/>',
     {"rail": -4.0, "pan": 30.0, "tilt": math.degrees(-0.3)}),
    # floating base on the generated floor: home is the neutral (every joint 0)
    ("crawler", '<joint_move joint="left_flip" deg="40" duration="1"/><joint_move joint="mast_yaw" deg="-60" duration="1"/>',
     {"left_flip": 40.0, "right_flip": 0.0, "mast_yaw": -60.0}),
])
def test_generated_robot_runs_pose_and_joint_move(robot: str, moves: str, target: dict[str, float],
                                                  tmp_path: Path) -> None:
    src = write_rig(tmp_path / "src") if robot == "rig" else write_crawler(tmp_path / "src")
    robots = tmp_path / "robots"
    new = cli("robots", "new", robot, "--mjcf", str(src), "--robots-dir", str(robots), data_home=tmp_path)
    assert new.returncode == 0, new.stderr
    out = tmp_path / "run"
    res = cli("run", "--robot", robot, "--robots-dir", str(robots), "--lockstep", "--no-live", "--out", str(out),
              "--xml", f'<pose name="home"/>{moves}', data_home=tmp_path)
    assert res.returncode == 0, res.stdout + res.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "done" and summary["outcomes"]["done"] == 3 and not summary["fell"]
    assert summary["extra"]["robot"] == robot
    timeline = json.loads((out / "timeline.json").read_text())
    assert [c["function"] for c in timeline["calls"]] == ["pose", "joint_move", "joint_move"]
    final = _final_positions_deg(out)
    errors = {j: abs(final[i] - t) for i, (j, t) in enumerate(target.items())}
    assert max(errors.values()) <= TOLERANCE_DEG, errors


def test_a_behaviour_and_stub_added_to_a_generated_robot(tmp_path: Path) -> None:
    """docs/guides/robots.md, "Add your robot": a behaviours module, an interface module and a channel, no other code."""
    robots = tmp_path / "robots"
    add_scan(install_package(generate_package("rig", write_rig(tmp_path / "src")), robots))
    show = cli("robots", "show", "rig", "--robots-dir", str(robots), data_home=tmp_path)
    assert show.returncode == 0, show.stderr
    assert "scan(times: int 1..10 = 1)  [channel head]  Sweep the camera from right to left `times` times" in show.stdout
    assert "channels: head(2)" in show.stdout
    out = tmp_path / "run"
    res = cli("run", "--robot", "rig", "--robots-dir", str(robots), "--lockstep", "--no-live", "--out", str(out),
              "--xml", '<scan times="1"/><joint_move joint="tilt" deg="20"/>', data_home=tmp_path)
    assert res.returncode == 0, res.stdout + res.stderr
    calls = json.loads((out / "timeline.json").read_text())["calls"]
    assert [(c["function"], c["channel"], c["outcome"]) for c in calls] == [
        ("scan", "head", "done"), ("joint_move", "joints", "done")]
    pan = []
    with open(out / "board_frames.jsonl", encoding="utf-8") as f:
        pan = [math.degrees(r["fields"]["positions"][1]) for r in iter_records(f)
               if r.get("type") == "TELEMETRY" and r["dir"] == "tx"]
    assert min(pan) < -60 + TOLERANCE_DEG and max(pan) > 60 - TOLERANCE_DEG  # the sweep reached both ends
    assert abs(_final_positions_deg(out)[2] - 20) <= TOLERANCE_DEG
