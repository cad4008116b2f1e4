"""Shared pieces of the servo-bus tests: the plant (a subprocess, or served in a thread of the test when a
test reads its registers), the board as a subprocess on the raw wire (:class:`tests.cfirmware.wire.Wire`),
and waits on board time (lockstep: nothing moves unless the test sends frames or ADVANCE)."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from protocol.codec import schema_for
from protocol.messages import PROTOCOL_VERSION, Advance, Hello, ServoFrame, Telemetry
from robots.registry import load_robot
from tests.cfirmware.wire import Wire

ARM = load_robot("arm")
N = ARM.servo_count
MASK = (1 << N) - 1
STEP = ARM.servos.model.resolution
ROOT = Path(__file__).resolve().parents[2]


class Plant:
    """``python -m firmware_sim.plant --robot arm --lockstep ...`` as a subprocess; ``pty`` is its bus."""

    def __init__(self, *args: str, protocol: str = "sts", baud: int = 1_000_000, lockstep: bool = True,
                 robot: str = "arm") -> None:
        cmd = [sys.executable, "-m", "firmware_sim.plant", "--robot", robot, "--protocol", protocol,
               "--baud", str(baud), *(["--lockstep"] if lockstep else []), *args]
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT,
                                     env=dict(os.environ, PYTHONUNBUFFERED="1"))
        assert self.proc.stdout is not None
        ready, _, _ = select.select([self.proc.stdout], [], [], 120)
        line = self.proc.stdout.readline().strip() if ready else ""
        if not line.startswith("plant: servo bus on "):
            self.close()
            raise AssertionError(f"the plant did not start: {line!r} {self.proc.stderr.read() if self.proc.stderr else ''}")
        self.pty = line.rsplit(" ", 1)[1]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()

    def __enter__(self) -> Plant:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextmanager
def plant_thread(robot: object = ARM, *, protocol: str = "sts", baud: int = 1_000_000,
                 conditions: object = None) -> Iterator[tuple[object, object, str, list[list[int]]]]:
    """The plant served in a thread of this process (lockstep): (world, plant bus, pty name, goals), where
    ``goals`` gets every control period's raw goal registers (servo order) as the world steps."""
    from firmware_sim.plant.bus import PlantBus
    from firmware_sim.plant.conditions import Conditions
    from firmware_sim.plant.server import serve, set_line_speed
    from firmware_sim.plant.world import World
    from firmware_sim.transports.ports import PtyPort

    world = World(robot, conditions=conditions or Conditions())  # type: ignore[arg-type]
    plant = PlantBus(world, lockstep=True, baud=baud, protocol=protocol)
    goals: list[list[int]] = []
    step = world.step

    def recording_step() -> None:
        goals.append([st.goal_steps for st in world.servos])
        step()

    world.step = recording_step  # type: ignore[method-assign]
    port = PtyPort()
    set_line_speed(port.slave, baud)
    stop = threading.Event()
    old = sys.getswitchinterval()
    sys.setswitchinterval(0.0002)  # the plant's thread gets its turns while the test waits on the wire
    th = threading.Thread(target=serve, args=(plant, port, stop), daemon=True)
    th.start()
    try:
        yield world, plant, port.name, goals
    finally:
        stop.set()
        th.join(10)
        port.close()
        sys.setswitchinterval(old)


def eventually(pred: Callable[[], bool], timeout: float = 10.0) -> bool:
    """True once ``pred()`` holds (checked every 5 ms, up to ``timeout`` s): for the in-thread plant, which
    reads what a board wrote to its pty on its own time, also after that board exited."""
    end = time.monotonic() + timeout
    done = threading.Event()
    while not pred():
        if time.monotonic() > end:
            return False
        done.wait(0.005)
    return True


def board(bus: str, tmp_path: Path, *args: str, name: str = "board.stderr") -> Wire:
    """A lockstep board (unless ``args`` say --realtime) for the arm on ``bus``, after HELLO."""
    clock = [] if "--realtime" in args else ["--lockstep"]
    w = Wire([*clock, "--robot", "arm", "--servo-bus", bus, *args], tmp_path / name)
    w.send(Hello(PROTOCOL_VERSION, schema_for(N).hash, 0))
    return w


def run_board(bus: str, *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    """``python -m firmware_sim --link pty --lockstep --robot arm --servo-bus BUS ARGS`` to its exit (start-up
    failures end it; stdin closed)."""
    return subprocess.run([sys.executable, "-m", "firmware_sim", "--link", "pty", "--lockstep", "--robot", "arm",
                           *(["--servo-bus", bus] if bus else []), *args],
                          cwd=ROOT, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL,
                          check=False)


def stream(w: Wire, targets: list[float], t0_us: int, t1_us: int, every_us: int = 10_000) -> None:
    """Frames holding ``targets`` (rad, servo order) from ``t0_us`` (excl.) to ``t1_us`` board time."""
    for t in range(t0_us + every_us, t1_us + 1, every_us):
        w.send(ServoFrame(t, MASK, targets))


def run_to(w: Wire, t_us: int) -> list[Telemetry]:
    """ADVANCE to ``t_us`` and wait for telemetry that far; returns all telemetry so far."""
    w.send(Advance(t_us))
    w.wait(lambda: any(t.board_time_us >= t_us for t in w.of(Telemetry)), what=f"telemetry at {t_us} us")
    return w.of(Telemetry)
