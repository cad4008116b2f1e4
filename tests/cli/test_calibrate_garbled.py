"""``ghostshell robots calibrate`` on a bus that answers with bad bytes: never a traceback.

The vendor SDKs trust what they read: a status packet that passes its checksum but carries fewer bytes than
asked for makes ``scservo_sdk``'s ``read2ByteTxRx`` (and ``dynamixel_sdk``'s ``read4ByteTxRx``) raise
``IndexError`` (a user's report: in the reference-pose step, from host/calibration/bus.py). Every SDK call
in host.calibration is wrapped: the answer is one line naming the servo (id and name), exit status 1,
nothing written, torque off. Fed here by a port that answers short (valid checksum/CRC, too few bytes) and
by the plant with two servos on one id (their replies collide into garbage)."""

from __future__ import annotations

import argparse
import struct
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import dynamixel_sdk.port_handler
import pytest
import scservo_sdk.port_handler

import host.cli
from firmware_sim.plant import dynamixel as dxl
from firmware_sim.plant import feetech as sts
from firmware_sim.plant.server import set_line_speed
from firmware_sim.transports.ports import PtyPort
from host.calibration.bus import REGISTERS, BusError, ServoBus
from host.commands.calibrate import run
from robots.hardware import CALIBRATION_FILE
from robots.loader import load_robot_dir
from tests.cli.test_calibrate import ROBOT, Hand, robots_dir, start_plant  # noqa: F401 - fixtures

MODEL = {"sts": 777, "dxl2": 1200}


def _answer(protocol: str, dev: int, inst: int, params: bytes, short_at: int) -> bytes:
    """A servo's status packet, checksum right, but too few data bytes for a read at ``short_at`` (STS: none, as
    scservo_sdk slices the checksum in as the first; Dynamixel: one of four)."""
    status = sts.status_packet if protocol == "sts" else dxl.status_packet
    if inst == 0x01:  # PING
        return status(dev, 0, b"" if protocol == "sts" else struct.pack("<HB", MODEL[protocol], 52))
    if inst == 0x02:  # READ addr, length
        addr, n = (params[0], params[1]) if protocol == "sts" else struct.unpack("<HH", params[:4])
        if addr == short_at:
            return status(dev, 0, b"" if protocol == "sts" else b"\x07")  # short: fewer bytes than asked for
        data = struct.pack("<H", MODEL[protocol]) if addr in (0, 3) else b""
        return status(dev, 0, (data + bytes(n))[:n])
    return status(dev, 0)  # WRITE: acknowledged


@pytest.fixture
def short_port(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[str], str]]:
    """A pty where every servo id answers properly but for present-position reads (one byte short)."""
    monkeypatch.setattr(scservo_sdk.port_handler, "LATENCY_TIMER", 100)
    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", 100)
    running: list[tuple[threading.Event, threading.Thread, PtyPort]] = []

    def start(protocol: str) -> str:
        port, stop = PtyPort(), threading.Event()
        set_line_speed(port.slave, 1_000_000)
        parser = sts.InstructionParser() if protocol == "sts" else dxl.DxlParser()
        short_at = REGISTERS[protocol].present_position

        def serve() -> None:
            import select

            while not stop.is_set():
                r, _, _ = select.select([port.master], [], [], 0.02)
                if r:
                    for ins in parser.feed(port.read()):
                        port.write(_answer(protocol, ins.id, ins.instruction, ins.params, short_at))

        th = threading.Thread(target=serve, daemon=True)
        th.start()
        running.append((stop, th, port))
        return port.name

    yield start
    for stop, th, port in running:
        stop.set()
        th.join(5)
        port.close()


def _args(robots_dir: Path, port: str, *extra: str) -> argparse.Namespace:
    return host.cli.build_parser(["robots"]).parse_args(
        ["robots", "calibrate", ROBOT, "--servo-bus", port, "--robots-dir", str(robots_dir), *extra])


@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
def test_the_sdk_itself_raises_on_a_short_reply(short_port, protocol: str) -> None:
    """What is being guarded against: the bare SDK call dies of IndexError (the user's traceback)."""
    import dynamixel_sdk
    import scservo_sdk

    sdk = scservo_sdk if protocol == "sts" else dynamixel_sdk
    port = sdk.PortHandler(short_port(protocol))
    assert port.openPort() and port.setBaudRate(1_000_000)
    try:
        ph = sdk.PacketHandler(0 if protocol == "sts" else 2.0)
        read = ph.read2ByteTxRx if protocol == "sts" else ph.read4ByteTxRx
        with pytest.raises(IndexError):
            read(port, 1, REGISTERS[protocol].present_position)
    finally:
        port.closePort()


@pytest.mark.parametrize("protocol", ["sts", "dxl2"])
def test_a_short_reply_is_one_line_naming_the_servo(robots_dir, short_port, capsys, protocol: str) -> None:  # noqa: F811
    port = short_port(protocol)
    robot = load_robot_dir(robots_dir / ROBOT)
    asked: list[str] = []
    status = run(_args(robots_dir, port, "--bus-protocol", protocol), ask=lambda p: asked.append(p) or "",
                 say=lambda line: None, live=lambda *a: None)
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert status == 1 and len(err) == 1, (status, err)
    first = robot.servos[0]
    assert err[0].startswith(f"ghostshell robots: servo {first.id} ({first.name}) answered a present-position read "
                             "with a garbled or short reply (IndexError"), err
    assert err[0].endswith("nothing written") and "Traceback" not in err[0]
    assert len(asked) == 1  # it failed reading the reference pose, as the user's did
    assert not (robots_dir / ROBOT / CALIBRATION_FILE).exists()


def test_every_sdk_call_is_wrapped(short_port) -> None:
    """ping, torque off and the position read: an SDK that raises becomes BusError naming the servo."""
    bus = ServoBus(short_port("sts"), 1_000_000, "sts", names={4: "wrist_flex"})
    bus.open()
    try:
        class Broken:
            def __getattr__(self, name: str) -> Callable[..., object]:
                def boom(*a: object) -> object:
                    raise struct.error("unpack requires a buffer of 2 bytes")
                return boom

        bus._ph = Broken()
        for call in (bus.ping, bus.torque_off, bus.position):
            with pytest.raises(BusError, match=r"^servo 4 \(wrist_flex\) answered a .* garbled or short reply "
                                               r"\(error: unpack requires"):
                call(4)
    finally:
        bus.close()


def test_two_servos_on_one_id_is_one_line(robots_dir, start_plant, capsys) -> None:  # noqa: F811
    """The plant's --duplicate: both servos answer id 3, their replies collide into garbage."""
    plant = start_plant(duplicate=frozenset({3}))
    hand = Hand(plant, load_robot_dir(robots_dir / ROBOT))
    status = run(_args(robots_dir, plant.port.name), ask=hand.ask, say=hand.say, live=hand.live)
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    assert status == 1 and len(err) == 1, (status, err)
    assert err[0].startswith("ghostshell robots: servo 3 (elbow_flex) answered a ping with a garbled reply"), err
    assert "two servos with this id" in err[0] and "Traceback" not in err[0]
    assert not (robots_dir / ROBOT / CALIBRATION_FILE).exists()
