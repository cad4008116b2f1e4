"""The link plan and the board's arguments of a session (host.run.launch), decided before anything starts."""

from __future__ import annotations

from pathlib import Path

import pytest

from host.link.errors import LinkConfigError
from host.run.launch import LinkPlan, board_args, heartbeat_for_grid
from host.run.options import SessionOptions
from protocol.linkspec import parse_link_spec
from protocol.messages import ConfigKey
from robots.registry import load_robot


def test_a_plan_refuses_links_it_cannot_use_and_fits_the_grid_to_the_line() -> None:
    robot = load_robot()
    with pytest.raises(LinkConfigError, match="the emulated board creates"):
        LinkPlan.of(parse_link_spec("pty"), SessionOptions(emulate_board=False), robot)
    with pytest.raises(LinkConfigError, match="virtual bus exists inside one process"):
        LinkPlan.of(parse_link_spec("can:virtual:x"), SessionOptions(emulate_board=True), robot)
    fast = LinkPlan.of(parse_link_spec("pty"), SessionOptions(), robot)
    assert fast.emulate and fast.log_suffix == ".jsonl" and fast.grid_note() is None
    assert fast.identity.servo_count == robot.servo_count
    slow = LinkPlan.of(parse_link_spec("pty"), SessionOptions(wire_baud=4_800), robot)
    assert slow.period_us > fast.period_us and fast.heartbeat_s == heartbeat_for_grid(fast.period_us)
    # the grid outgrew the board's 200 ms watchdog: the handshake raises it, heartbeats fill half of it
    assert dict(slow.link_config)[ConfigKey.WATCHDOG_MS] >= 3 * slow.period_us // 1000 and not fast.link_config
    assert slow.heartbeat_s == dict(slow.link_config)[ConfigKey.WATCHDOG_MS] / 2000
    with pytest.raises(LinkConfigError, match="--baud 1200 is too slow"):
        LinkPlan.of(parse_link_spec("pty"), SessionOptions(wire_baud=1_200), robot)
    note = slow.grid_note()
    assert note is not None and note.startswith("--baud 4800: one 12-servo frame takes")


def test_the_board_gets_the_options_that_shape_its_world(tmp_path: Path) -> None:
    robot = load_robot()
    opts = SessionOptions(lockstep=True, wire_baud=57_600, faults="drop=0.1", fault_seed=3, firmware="c",
                          pushes=("1:5,0,0",), servo_bus=("--servo-bus", "/dev/null"))
    args = board_args(opts, robot, tmp_path, "bottles", ".jsonl")
    assert args[0] == "--lockstep" and args[args.index("--scene") + 1] == "bottles"
    assert args[args.index("--log") + 1] == str(tmp_path / "board_frames.jsonl")
    for pair in (["--push", "1:5,0,0"], ["--baud", "57600"], ["--faults", "drop=0.1", "--fault-seed", "3"],
                 ["--firmware", "c"], ["--servo-bus", "/dev/null"]):
        i = args.index(pair[0])
        assert args[i:i + len(pair)] == pair
    assert "--firmware" not in board_args(SessionOptions(), robot, tmp_path, "empty", ".jsonl")
