"""The C firmware's start-up checks on a servo bus and its bus period (gs_board_boot, gs_board.c).

Boot checks, as the Python board's start-up (firmware_sim/servobus/driver.py) and in its words: a servo that does
not answer its ping, answers garbled (two servos with one id collide on the half-duplex line), reports another
model number than the robot's hardware.toml, or stands outside its step range refuses the start: one line
``board: servo N (name) ...; torque left off``, torque off for the whole bus, exit status 2. The plant runs in a
thread of this process (its servos start with torque on, so "torque off" is read back from the plant's own
state) or as ``python -m firmware_sim.plant`` (then read back with the vendor SDK, as a user would).

Bus period: from the servo count, protocol, baud and the servos' return delay (written to 0 at boot and read
back) the firmware chooses to write goals every k control ticks, the smallest k whose period holds one bus
cycle with 20 % to spare, and says it in one boot line. Every wait here is for a condition (a line, an exit),
with a time bound only as a failure bound.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import scservo_sdk.port_handler
from scservo_sdk import COMM_SUCCESS, PacketHandler, PortHandler

from firmware_sim.cfirmware.build import build
from firmware_sim.plant.conditions import Conditions
from firmware_sim.plant.devices import REG
from robots.registry import load_robot
from tests.cfirmware.test_c_servo_bus import ROBOT, ROOT, WAIT_S, _exe, _readline, _wait_for, plant_thread

ARM = load_robot("arm")


def _env() -> dict[str, str]:
    return dict(os.environ, ASAN_OPTIONS="detect_leaks=0:abort_on_error=0",
                UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")


def _boot(exe: Path, tty: str, baud: int, protocol: str, *extra: str) -> subprocess.CompletedProcess[str]:
    """The native firmware on ``tty`` until it exits (a refused boot exits by itself)."""
    r = subprocess.run([str(exe), "--bus", f"tty:{tty}:{baud}", "--protocol", protocol, *extra, "--host", "pty"],
                       capture_output=True, text=True, stdin=subprocess.DEVNULL, env=_env(), timeout=WAIT_S)
    assert "AddressSanitizer" not in r.stderr and "runtime error" not in r.stderr, r.stderr[-3000:]
    return r


def _board_lines(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ln.startswith("board: ")]


REFUSALS = [
    ("sts", Conditions(models={4: 999}), 4,
     "reports model number 999, the robot's hardware.toml says 777; torque left off"),
    ("dxl2", Conditions(models={4: 1060}), 4,
     "reports model number 1060, the robot's hardware.toml says 1200; torque left off"),
    ("sts", Conditions(missing=frozenset({3})), 3,
     "does not answer a ping (missing, unpowered, or another id or baud); torque left off"),
    ("dxl2", Conditions(missing=frozenset({3})), 3,
     "does not answer a ping (missing, unpowered, or another id or baud); torque left off"),
    ("sts", Conditions(duplicate=frozenset({2})), 2,
     "answers a ping garbled (two servos with this id, or noise on the bus); torque left off"),
    ("dxl2", Conditions(duplicate=frozenset({2})), 2,
     "answers a ping garbled (two servos with this id, or noise on the bus); torque left off"),
    ("sts", Conditions(offsets={5: 900}), 5, "outside its range"),
    ("dxl2", Conditions(offsets={5: -900}), 5, "outside its range"),
]


@pytest.mark.parametrize("protocol,conditions,sid,why", REFUSALS,
                         ids=[f"{p}-{w.split(' (')[0].split(',')[0].replace(' ', '_')}" for p, _, _, w in REFUSALS])
def test_a_boot_check_refuses_the_start_with_one_line_and_torque_off(protocol: str, conditions: Conditions, sid: int,
                                                                       why: str) -> None:
    servo = ROBOT.servos[sid - 1]
    with plant_thread(protocol, 1_000_000, conditions) as (plant, tty):
        for st in plant.world.servos:  # a robot left under torque (Dynamixel X servos power up with it off)
            st.torque = True
        r = _boot(_exe(), tty, 1_000_000, protocol, "--lockstep")
        # the whole bus torque off: the firmware's last bytes, which the plant's thread takes in after it exited
        # (the plant's missing servo is not on the bus at all)
        _wait_for(lambda: not any(st.torque for st in plant.world.servos if st.id not in conditions.missing),
                  "torque off for every servo")
    assert r.returncode == 2, r.stderr[-3000:]
    lines = _board_lines(r.stderr)
    assert len(lines) == 1, r.stderr[-3000:]
    assert lines[0].startswith(f"board: servo {sid} ({servo.name}) ") and why in lines[0], lines
    if "outside its range" in why:
        assert re.search(r"is at -?\d+\.\d deg, outside its range -?\d+\.\.-?\d+ deg \(steps \d+, limits \d+\.\.\d+\); "
                         r"torque left off: move it into its range by hand and start again$", lines[0]), lines[0]
    assert "listening on" in r.stdout  # the host link was up: the refusal is the bus's, not a usage error


def test_the_users_model_mismatch_against_the_plant_process_and_the_vendor_sdk(monkeypatch: pytest.MonkeyPatch) -> None:
    """The report's case: ``python -m firmware_sim.plant --model 4=999``; torque read back with scservo_sdk."""
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim.plant", "--protocol", "sts", "--baud", "1000000",
                             "--lockstep", "--model", "4=999"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            cwd=ROOT, stdin=subprocess.DEVNULL)
    try:
        assert proc.stdout is not None
        tty = _readline(proc.stdout, "plant: servo bus on ", proc).split()[-1]
        r = _boot(_exe(), tty, 1_000_000, "sts", "--lockstep")
        assert r.returncode == 2, r.stderr[-3000:]
        assert _board_lines(r.stderr) == [f"board: servo 4 ({ROBOT.servos[3].name}) reports model number 999, the "
                                          "robot's hardware.toml says 777; torque left off"], r.stderr[-3000:]
        monkeypatch.setattr(scservo_sdk.port_handler, "LATENCY_TIMER", 100)
        port, ph = PortHandler(tty), PacketHandler(0)
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            for s in ROBOT.servos:
                on, result, _ = ph.read1ByteTxRx(port, s.id, REG.TORQUE_ENABLE)
                assert result == COMM_SUCCESS and on == 0, (s.id, on, ph.getTxRxResult(result))
        finally:
            port.closePort()
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)


def test_the_launcher_says_a_refusal_in_one_line_and_exits_2(tmp_path: Path) -> None:
    """``python -m firmware_sim --firmware c --servo-bus PORT:BAUD``: the Python board's line
    (``board: servo bus PORT: servo 3 (...) ...``, which host.link.board_process reports) and status 2."""
    proc = subprocess.Popen([sys.executable, "-m", "firmware_sim.plant", "--protocol", "sts", "--baud", "1000000",
                             "--lockstep", "--missing", "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            cwd=ROOT, stdin=subprocess.DEVNULL)
    try:
        assert proc.stdout is not None
        tty = _readline(proc.stdout, "plant: servo bus on ", proc).split()[-1]
        r = subprocess.run([sys.executable, "-m", "firmware_sim", "--link", "pty", "--firmware", "c", "--servo-bus",
                            f"{tty}:1000000", "--lockstep"], capture_output=True, text=True, cwd=ROOT,
                           stdin=subprocess.DEVNULL, timeout=300)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
    assert r.returncode == 2, r.stderr[-3000:]
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert lines == [f"board: servo bus {tty}: servo 3 ({ROBOT.servos[2].name}) does not answer a ping (missing, "
                     "unpowered, or another id or baud); torque left off"], r.stderr[-3000:]


def test_a_healthy_bus_boots_and_its_return_delay_is_written_to_zero() -> None:
    """Dynamixel X ships with a 500 us return delay (address 9): the firmware writes 0 (torque off) at boot."""
    with plant_thread("dxl2", 1_000_000) as (plant, tty):
        assert all(d.return_delay_us == 500 for d in (plant.devices[s.id] for s in ROBOT.servos))
        proc = subprocess.Popen([str(_exe()), "--bus", f"tty:{tty}:1000000", "--protocol", "dxl2", "--lockstep",
                                 "--host", "pty"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                stdin=subprocess.DEVNULL, env=_env())
        try:
            assert proc.stderr is not None
            line = _readline(proc.stderr, "board: servo bus: ", proc)
            delays = [plant.devices[s.id].return_delay_us for s in ROBOT.servos]
        finally:
            proc.send_signal(signal.SIGTERM)
            _, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err.decode()[-3000:]
    assert delays == [0] * len(delays)
    assert line.startswith(f"board: servo bus: {ROBOT.servo_count} servos need ") and "return delay" not in line, line
    assert "goals every tick (lockstep: the plant steps on each goal write)" in line, line


# -- the bus period (realtime) ------------------------------------------------------------------------------

class _RealtimePlant:
    """``python -m firmware_sim.plant`` in realtime (its world on the wall clock); after the block, ``goal_writes``:
    the goal SYNC WRITEs it counted (its exit line ``plant: servo bus: N ticks, ...``)."""

    def __init__(self, protocol: str, baud: int, *extra: str) -> None:
        self.proc = subprocess.Popen([sys.executable, "-m", "firmware_sim.plant", "--protocol", protocol, "--baud",
                                      str(baud), *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=ROOT,
                                     stdin=subprocess.DEVNULL)
        self.goal_writes = -1

    def __enter__(self) -> str:
        assert self.proc.stdout is not None
        return _readline(self.proc.stdout, "plant: servo bus on ", self.proc).split()[-1]

    def __exit__(self, *exc: object) -> None:
        self.proc.send_signal(signal.SIGTERM)
        try:
            _, err = self.proc.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            _, err = self.proc.communicate()
        m = re.search(rb"plant: servo bus: (\d+) ticks", err)
        self.goal_writes = int(m.group(1)) if m else -1


_STATS = re.compile(r"^S .*\bticks=(\d+)\b.*\bticks_skipped=(\d+) overruns=(\d+)\b", re.M)


def _run_realtime(exe: Path, tty: str, baud: int, protocol: str, ticks: int, log: Path) -> tuple[str, int, int]:
    """The firmware in realtime until its stats line counts ``ticks``: (its bus period line, the ticks it ran (not
    those it skipped to catch up on a loaded machine), the ticks that started a period late)."""
    with open(log, "wb") as err:
        proc = subprocess.Popen([str(exe), "--bus", f"tty:{tty}:{baud}", "--protocol", protocol, "--realtime",
                                 "--host", "pty"], stdout=subprocess.DEVNULL, stderr=err, stdin=subprocess.DEVNULL,
                                env=_env())
        try:
            end = time.monotonic() + WAIT_S
            while True:  # the stats line comes every 500 ticks (1 s at 500 Hz): polled, bounded
                text = log.read_text()
                seen = [int(m.group(1)) for m in _STATS.finditer(text)]
                if seen and seen[-1] >= ticks:
                    break
                assert proc.poll() is None, text[-3000:]
                assert time.monotonic() < end, f"no stats line with {ticks} ticks: {text[-3000:]}"
                time.sleep(0.1)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(30)
    text = log.read_text()
    assert "AddressSanitizer" not in text and "runtime error" not in text, text[-3000:]
    line = next(ln for ln in text.splitlines() if ln.startswith("board: servo bus: "))
    m = list(_STATS.finditer(text))[-1]
    return line, int(m.group(1)) - int(m.group(2)), int(m.group(3))


def test_coco_on_sts_at_1_mbaud_writes_goals_every_2_ticks_and_no_longer_overruns(tmp_path: Path) -> None:
    """12 servos: sync write 44 B + sync read request 20 B + 12 answers of 12 B = 2.08 ms > 2 ms: k = 2."""
    plant = _RealtimePlant("sts", 1_000_000)
    with plant as tty:
        line, ticks, overruns = _run_realtime(_exe(), tty, 1_000_000, "sts", 1500, tmp_path / "fw.stderr")
    assert line == "board: servo bus: 12 servos need 2.1 ms a cycle at 1000000 baud: goals every 2 ticks (250 Hz)"
    # goals every 2nd tick (the plant counts them; the board's last ticks after its stats line: a few more)
    assert ticks / 2 * 0.9 - 5 <= plant.goal_writes <= ticks / 2 * 1.1 + 5, (ticks, plant.goal_writes)
    # before: every tick overran (the report); a loaded machine still makes some late, not all
    assert overruns <= ticks * 3 // 4, (ticks, overruns)
    assert "stopped answering" not in (tmp_path / "fw.stderr").read_text()


def test_coco_on_dynamixel_at_57600_baud_writes_goals_every_37_ticks(tmp_path: Path) -> None:
    plant = _RealtimePlant("dxl2", 57_600)
    with plant as tty:
        line, ticks, _ = _run_realtime(_exe(), tty, 57_600, "dxl2", 1000, tmp_path / "fw.stderr")
    # 74 B + 26 B + 12 x 21 B at 57 600 baud = 61.1 ms (return delay written to 0): 61.1 x 1.2 / 2 -> 37 ticks
    assert line == "board: servo bus: 12 servos need 61.1 ms a cycle at 57600 baud: goals every 37 ticks (13.5 Hz)"
    assert ticks / 37 * 0.8 - 3 <= plant.goal_writes <= ticks / 37 * 1.2 + 3, (ticks, plant.goal_writes)


def test_the_arm_on_sts_at_1_mbaud_writes_goals_every_tick(tmp_path: Path) -> None:
    plant = _RealtimePlant("sts", 1_000_000, "--robot", ARM.name)
    with plant as tty:
        line, ticks, _ = _run_realtime(build("native-asan", ARM), tty, 1_000_000, "sts", 500, tmp_path / "fw.stderr")
    assert line == "board: servo bus: 6 servos need 1.1 ms a cycle at 1000000 baud: goals every tick (500 Hz)"
    assert ticks * 0.9 - 5 <= plant.goal_writes <= ticks * 1.1 + 5, (ticks, plant.goal_writes)
