"""Issue 42 item 5, as a new user meets it: a real third-party arm MJCF through ``ghostshell robots new``,
``robots check``, the ``try:`` line it prints, ``run``, ``render`` and the MCP server, as real subprocesses.

The arm is the test suite's third-party-style mesh arm (:mod:`support.mesh_robot`: STL meshes through an
include, no floor), its MJCF rewritten the way real models are: every actuator's ``ctrlrange`` (in radians,
as MuJoCo reads it) 1 deg inside its joint's ``range`` (the joint range the mechanical stop, the
ctrlrange the software limit). That was refused; now each servo reaches the intersection, with one note.
"""

from __future__ import annotations

import json
import math
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from protocol.framelog import iter_records
from support.mesh_robot import JOINTS, write_mesh_arm
from support.robot_samples import cli, line_of, one_line_error

#: the mesh arm's joint ranges (deg), support/mesh_robot.py's _LINKS
RANGES = dict(zip(JOINTS, ((-110, 110), (-100, 100), (-97, 97), (-95, 95), (-160, 160), (-10, 100))))


def third_party_arm(tmp_path: Path, ctrl: dict[str, tuple[float, float]] | None = None) -> Path:
    """The mesh arm's MJCF with each ctrlrange in radians: ``ctrl`` (deg) per joint, else 1 deg inside the joint."""
    write_mesh_arm(tmp_path, segments=8)
    mjcf = tmp_path / "mjcf" / "arm.xml"
    ctrl = ctrl or {}

    def rewrite(m: re.Match[str]) -> str:
        joint = m.group(1)
        lo, hi = ctrl.get(joint, (RANGES[joint][0] + 1, RANGES[joint][1] - 1))
        return f'joint="{joint}" ctrlrange="{math.radians(lo):.6f} {math.radians(hi):.6f}"'

    mjcf.write_text(re.sub(r'joint="(\w+)" ctrlrange="[^"]*"', rewrite, mjcf.read_text()))
    return mjcf


def _env(data_home: Path) -> dict[str, str]:
    """The environment :func:`support.robot_samples.cli` gives a command (its own user data folder)."""
    env = {k: v for k, v in os.environ.items() if k != "GHOSTSHELL_ROBOTS"}
    return env | {"XDG_DATA_HOME": str(data_home), "MUJOCO_GL": "egl"}


def _notes(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("note: ")]


def _new(tmp_path: Path, mjcf: Path, name: str = "thirdarm") -> Any:
    return cli("robots", "new", name, "--mjcf", str(mjcf), "--robots-dir", str(tmp_path / "robots"),
               data_home=tmp_path)


def _final_deg(run_dir: Path, index: int) -> float:
    last = None
    with open(run_dir / "board_frames.jsonl", encoding="utf-8") as f:
        for rec in iter_records(f):
            if rec.get("type") == "TELEMETRY" and rec["dir"] == "tx":
                last = rec["fields"]["positions"]
    assert last is not None, "the board sent no telemetry"
    return math.degrees(last[index])


def test_new_check_and_load_print_the_ctrlrange_note_once(tmp_path: Path) -> None:
    new = _new(tmp_path, third_party_arm(tmp_path))
    assert new.returncode == 0, new.stderr
    notes = [n for n in _notes(new.stderr) if "ctrlrange" in n]
    assert len(notes) == 1, new.stderr
    assert notes[0].startswith("note: ctrlrange narrower than the joint range on 6 servo(s), so the servo range is the "
                               "intersection: shoulder_pan [-109, 109] deg (joint [-110, 110] deg)"), notes[0]
    assert "Traceback" not in new.stderr
    servos = (tmp_path / "robots" / "thirdarm" / "servos.toml").read_text()
    assert "min_deg = -96.0\nmax_deg = 96.0   # joint range -97..97 within actuator ctrlrange -96..96" in servos

    check = cli("robots", "check", "thirdarm", "--robots-dir", str(tmp_path / "robots"), data_home=tmp_path)
    assert check.returncode == 0, check.stderr
    assert _notes(check.stderr) == notes  # the same note, once
    assert check.stdout.startswith("robot thirdarm: ok (6 servos, poses zero, home;")

    for args in (("robots", "show", "thirdarm"), ("robots", "list")):  # loading it says nothing again
        res = cli(*args, "--robots-dir", str(tmp_path / "robots"), data_home=tmp_path)
        assert res.returncode == 0 and not _notes(res.stderr), res.stderr
    show = cli("robots", "show", "thirdarm", "--robots-dir", str(tmp_path / "robots"), data_home=tmp_path).stdout
    assert "servos: 1:shoulder_pan[-109..109], 2:shoulder_lift[-99..99], 3:elbow_flex[-96..96]" in show


def test_a_hand_edited_table_is_noted_on_the_first_load_only(tmp_path: Path) -> None:
    """A table that keeps the joint range where the ctrlrange is narrower loads (targets beyond the ctrlrange are
    not reached): the first command after the edit says so in one note; the next ones (a pass recorded) do not."""
    assert _new(tmp_path, third_party_arm(tmp_path)).returncode == 0
    servos = tmp_path / "robots" / "thirdarm" / "servos.toml"
    servos.write_text(servos.read_text().replace("min_deg = -96.0\nmax_deg = 96.0", "min_deg = -97.0\nmax_deg = 97.0"))
    said = []
    for _ in range(2):
        res = cli("robots", "show", "thirdarm", "--robots-dir", str(tmp_path / "robots"), data_home=tmp_path)
        assert res.returncode == 0, res.stderr
        said.append(_notes(res.stderr))
    assert len(said[0]) == 1 and said[1] == [], said
    assert said[0][0].startswith(f"note: robot thirdarm: {servos}: the servo table keeps the joint range where the "
                                 "actuator's ctrlrange is narrower") and "elbow_flex [-97, 97] (reachable [-96, 96])" in said[0][0]


def test_a_wider_ctrlrange_is_clamped_with_one_note(tmp_path: Path) -> None:
    wide = {j: (lo - 20, hi + 20) for j, (lo, hi) in RANGES.items()}
    new = _new(tmp_path, third_party_arm(tmp_path, wide))
    assert new.returncode == 0, new.stderr
    notes = [n for n in _notes(new.stderr) if "ctrlrange" in n]
    assert len(notes) == 1 and notes[0].startswith("note: ctrlrange wider than the joint range on 6 servo(s), so the "
                                                   "servo range is the joint range: shoulder_pan [-110, 110] deg "
                                                   "(ctrlrange [-130, 130] deg)"), new.stderr


@pytest.mark.parametrize("case", ["outside above", "outside below", "inverted ctrlrange", "NaN ctrlrange",
                                  "inverted joint range", "NaN joint range"])
def test_hostile_ranges_are_one_line_exit_2(tmp_path: Path, case: str) -> None:
    mjcf = third_party_arm(tmp_path)
    text = mjcf.read_text()
    ctrl = re.compile(r'(joint="elbow_flex") ctrlrange="[^"]*"')
    joint = re.compile(r'(<joint name="elbow_flex"[^>]*) range="[^"]*"')
    edit = {"outside above": (ctrl, r'\1 ctrlrange="2 3"'), "outside below": (ctrl, r'\1 ctrlrange="-3 -2"'),
            "inverted ctrlrange": (ctrl, r'\1 ctrlrange="1 -1"'), "NaN ctrlrange": (ctrl, r'\1 ctrlrange="nan 1"'),
            "inverted joint range": (joint, r'\1 range="97 -97"'), "NaN joint range": (joint, r'\1 range="nan 97"')}
    pattern, repl = edit[case]
    mjcf.write_text(pattern.sub(repl, text))
    line = one_line_error(_new(tmp_path, mjcf))
    at = line_of(mjcf, '<position name="elbow_flex"') if "ctrlrange" in case or "outside" in case else \
        line_of(mjcf, '<joint name="elbow_flex"')
    assert line.startswith(f"ghostshell robots: {mjcf}:{at}: "), line
    assert not (tmp_path / "robots" / "thirdarm").exists()


@pytest.mark.parametrize("edit", ['ctrlrange="2 3"', 'ctrlrange="nan 1"', 'ctrlrange="1 -1"'])
def test_a_package_edited_into_a_hostile_range_is_one_line_exit_2(tmp_path: Path, edit: str) -> None:
    """The same refusals when the package's own MJCF is edited after ``robots new``: ``robots check`` and ``run``."""
    assert _new(tmp_path, third_party_arm(tmp_path)).returncode == 0
    mjcf = tmp_path / "robots" / "thirdarm" / "arm.xml"
    mjcf.write_text(re.sub(r'(joint="elbow_flex") ctrlrange="[^"]*"', rf"\1 {edit}", mjcf.read_text()))
    at = f"{mjcf}:{line_of(mjcf, '<position name=.elbow_flex.')}: "
    check = one_line_error(cli("robots", "check", "thirdarm", "--robots-dir", str(tmp_path / "robots"),
                               data_home=tmp_path))
    assert check.startswith(f"ghostshell robots: {at}"), check
    run = one_line_error(cli("run", "--robot", "thirdarm", "--robots-dir", str(tmp_path / "robots"), "--lockstep",
                             "--no-live", "--out", str(tmp_path / "run"), "--xml", '<pose name="home"/>',
                             data_home=tmp_path))
    assert run.startswith("ghostshell run: ") and at in run, run


def test_the_try_line_runs_as_printed_and_moves_a_joint_visibly(tmp_path: Path) -> None:
    new = _new(tmp_path, third_party_arm(tmp_path))
    assert new.returncode == 0, new.stderr
    last = new.stdout.strip().splitlines()[-1]
    assert last.startswith("try: ghostshell run --robot thirdarm --robots-dir "), last
    argv = shlex.split(last.removeprefix("try: "))
    assert argv[0] == "ghostshell"
    move = re.search(r'<joint_move joint="(\w+)" deg="(-?\d+)" duration="1"/>', last)
    assert move is not None, last
    joint, deg = move.group(1), float(move.group(2))
    lo, hi = RANGES[joint][0] + 1, RANGES[joint][1] - 1
    assert lo <= deg <= hi and abs(deg) >= 0.25 * (hi - lo), last  # a clear fraction of its range from home (0)
    assert joint not in ("wrist_roll", "gripper", "shoulder_pan"), last  # a move that shows: the arm stands along z

    cwd = tmp_path / "cwd"  # the run writes its artefacts under the current folder, as for the user
    cwd.mkdir()
    res = subprocess.run([sys.executable, "-m", "host", *argv[1:]], cwd=cwd, capture_output=True, text=True,
                         timeout=240, env=_env(tmp_path))
    assert res.returncode == 0, res.stdout + res.stderr
    out = Path(re.search(r"artefacts in (\S+?)/?:", res.stdout).group(1))  # type: ignore[union-attr]
    out = out if out.is_absolute() else cwd / out
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcome"] == "done"
    assert abs(_final_deg(out, JOINTS.index(joint)) - deg) <= 3.0

    # and the run renders (ghostshell render): the arm framed on a floor, not a black void
    video = tmp_path / "try.mp4"
    render = cli("render", str(out), "--out", str(video), "--robots-dir", str(tmp_path / "robots"), "--quiet",
                 data_home=tmp_path)
    assert render.returncode == 0, render.stderr
    import imageio_ffmpeg

    frames = imageio_ffmpeg.read_frames(str(video))
    meta = next(frames)
    w, h = meta["size"]
    first = np.frombuffer(next(frames), dtype=np.uint8).reshape(h, w, 3)[: h - 72]
    assert float(np.mean(first.max(axis=2) < 24)) < 0.35


def test_out_of_range_names_the_joints_own_range(tmp_path: Path) -> None:
    """A program known in full is checked before the board starts (host.shell.precheck): each bad deg is
    refused in one line with the joint's own range, exit 2, and nothing runs (no robot moved)."""
    assert _new(tmp_path, third_party_arm(tmp_path)).returncode == 0
    for deg in ("500", "120"):  # outside every joint's range / inside the widest (shoulder_pan's) but not its own
        xml = f'<joint_move joint="shoulder_lift" deg="10" duration="1"/><joint_move joint="elbow_flex" deg="{deg}"/>'
        res = cli("run", "--robot", "thirdarm", "--robots-dir", str(tmp_path / "robots"), "--lockstep", "--no-live",
                  "--out", str(tmp_path / f"run{deg}"), "--xml", xml, data_home=tmp_path)
        text = res.stdout + res.stderr
        assert res.returncode == 2, text
        assert f"column 58: <joint_move> deg='{deg}' is out of range [-96, 96] for joint elbow_flex; nothing was run" \
            in text, text
        assert "Error:" not in text and "[-159" not in text and "[-160" not in text, text
        assert len(text.strip().splitlines()) == 1, text
        assert not (tmp_path / f"run{deg}" / "timeline.json").exists()


def test_mcp_tool_out_of_range_names_the_joints_own_range(tmp_path: Path) -> None:
    import anyio
    from mcp import Client
    from mcp.client.stdio import StdioServerParameters

    assert _new(tmp_path, third_party_arm(tmp_path)).returncode == 0
    params = StdioServerParameters(command=sys.executable, args=[
        "-m", "host", "mcp", "--robot", "thirdarm", "--robots-dir", str(tmp_path / "robots"), "--lockstep",
        "--out", str(tmp_path / "mcp")], env=_env(tmp_path))

    async def main() -> list[Any]:
        async with Client(params, read_timeout_seconds=120) as client:
            tools = {t.name: t for t in (await client.list_tools()).tools}
            deg = tools["joint_move"].input_schema["properties"]["deg"]
            assert "maximum" not in deg and "minimum" not in deg  # no widest-joint bound to misreport
            return [await client.call_tool("joint_move", {"joint": "elbow_flex", "deg": d}) for d in (500, 120)]

    results = anyio.run(main, backend="asyncio")
    for d, result in zip((500, 120), results):
        text = result.content[0].text
        assert f"<joint_move> deg='{d}.0' is out of range [-96, 96] for joint elbow_flex" in text, text
        assert "ValueError" not in text and "validation error" not in text, text


GUIDE = Path(__file__).resolve().parents[2] / "docs" / "guides" / "robots.md"


def _guide_section() -> str:
    text = GUIDE.read_text(encoding="utf-8")
    start = text.index("### From a third-party MJCF to a video")
    return text[start:text.index("\n## ", start) if "\n## " in text[start:] else len(text)]


def test_the_robots_guide_walk_runs_as_written(tmp_path: Path) -> None:
    """docs/guides/robots.md, "From a third-party MJCF to a video": every command of its sh block, as written
    (the MJCF path replaced by this arm's), and the output it shows."""
    section = _guide_section()
    block = section[section.index("```sh\n") + 6:]
    block = block[:block.index("```")]
    commands = [line.split("  #")[0].strip() for line in block.splitlines() if line.strip()]
    assert [c.split()[1:3] for c in commands][:4] == [["robots", "new"], ["robots", "check"], ["run", "--robot"],
                                                      ["render", "runs/program"]]
    mjcf = third_party_arm(tmp_path)
    cwd = tmp_path / "cwd"
    cwd.mkdir()
    outputs = []
    for command in commands:
        argv = shlex.split(command.replace("~/models/arm/arm.xml", str(mjcf)))
        assert argv[0] == "ghostshell", command
        res = subprocess.run([sys.executable, "-m", "host", *argv[1:]], cwd=cwd, capture_output=True, text=True,
                             timeout=240, env=_env(tmp_path))
        assert res.returncode == 0, f"{command}\n{res.stdout}\n{res.stderr}"
        outputs.append(res)
    assert (cwd / "runs" / "program" / "run.mp4").stat().st_size > 10_000
    shown = [line for line in section.splitlines() if line.startswith(("try: ", "note: ctrlrange", "ghostshell run: the program"))]
    new, check = outputs[0], outputs[1]
    try_line = new.stdout.strip().splitlines()[-1]
    assert shown[0] == try_line.replace(f" --robots-dir {tmp_path}", "")
    note = shown[1].removesuffix(", ...")
    assert _notes(new.stderr)[0].startswith(note) and _notes(check.stderr)[0].startswith(note), new.stderr
    assert commands[2] == f"{try_line.removeprefix('try: ')} --video"  # the walk runs the try: line
    res = subprocess.run([sys.executable, "-m", "host", "run", "--robot", "myarm", "--lockstep", "--no-live", "--xml",
                          '<joint_move joint="elbow_flex" deg="120"/>'], cwd=cwd, capture_output=True, text=True,
                         timeout=240, env=_env(tmp_path))
    assert shown[2] in res.stdout + res.stderr
