"""Board settings (rates, safety limits) with validation that gives clear errors."""

from __future__ import annotations

import os
from dataclasses import dataclass

from robots.registry import DEFAULT_ROBOT


class ConfigError(ValueError):
    """An inconsistent board setting (message says which and why)."""


#: the environment variable that picks the per-tick servo path when ``BoardConfig.kernel`` is None
KERNEL_ENV = "GHOSTSHELL_BOARD_KERNEL"
#: the per-tick servo paths: C when it builds (else Python, with a note), C or an error, the Python reference
KERNELS = ("native", "native!", "python")


def kernel_choice(override: str | None = None) -> str:
    """One of :data:`KERNELS`: ``override``, else ``$GHOSTSHELL_BOARD_KERNEL``, else ``"native"``.

    Raises :class:`ConfigError` naming the bad value and where it came from."""
    raw = override if override is not None else os.environ.get(KERNEL_ENV) or "native"
    choice = raw.strip().lower()
    if choice not in KERNELS:
        where = "kernel" if override is not None else f"${KERNEL_ENV}"
        raise ConfigError(f"board kernel must be native, native! or python, got {raw!r} ({where})")
    return choice


@dataclass
class BoardConfig:
    """Everything the board core needs to know; times in microseconds unless named otherwise."""

    rate_hz: int = 500  # control loop rate
    dt: float = 0.002  # physics step (s); the tick period must be a whole number of steps
    lockstep: bool = False
    telemetry_rate_hz: int = 50  # TELEMETRY and SIM_STATE rate
    watchdog_ms: int = 200  # link silence before holding position
    crouch_after_ms: int = 1000  # further silence before the safe crouch and the latched fault
    max_late_us: int = 20_000  # frames due earlier than now - this are rejected as LATE
    max_future_us: int = 5_000_000  # frames due later than now + this are rejected as TOO_FAR_FUTURE
    buffer_depth: int = 256  # jitter buffer capacity in frames
    resume_gap_us: int = 50_000  # idle servo: a new stream starts from where it is after this gap
    crouch_speed: float = 1.0  # rad/s while crouching on a watchdog fault
    #: leaving a HOLD/ESTOP: the gap between the held command and the stream's first target closes with
    #: a minimum-jerk blend at this peak speed (rad/s, ~150 deg/s), over at least resume_blend_min_us
    resume_speed: float = 2.6
    resume_blend_min_us: int = 40_000
    robot: str = DEFAULT_ROBOT  # the robot it drives: a name on the robot search path or a folder (robots.registry)
    robots_dir: str | None = None  # searched first for ``robot`` (--robots-dir)
    scene: str | None = None  # objects in the world: one of the robot's scenes (None: its default scene)
    #: the per-tick servo path: "native" (C when it builds, else Python), "native!" (C or an error), "python"
    #: (the reference); None: ``$GHOSTSHELL_BOARD_KERNEL``, else native (see :mod:`firmware_sim.native`)
    kernel: str | None = None

    @property
    def tick_us(self) -> int:
        return 1_000_000 // self.rate_hz

    @property
    def substeps(self) -> int:
        return round(1.0 / (self.rate_hz * self.dt))

    @property
    def telemetry_every(self) -> int:
        """Ticks between telemetry reports (at least 1)."""
        return max(1, round(self.rate_hz / self.telemetry_rate_hz))

    def validate(self) -> BoardConfig:
        """Raise :class:`ConfigError` unless the settings are consistent; returns self."""
        if not 1 <= self.rate_hz <= 10_000:
            raise ConfigError(f"rate must be 1..10000 Hz, got {self.rate_hz}")
        if 1_000_000 % self.rate_hz:
            raise ConfigError(f"rate {self.rate_hz} Hz does not give a whole-microsecond tick period")
        if not 1e-5 <= self.dt <= 0.02:
            raise ConfigError(f"dt must be 1e-5..0.02 s, got {self.dt}")
        ratio = 1.0 / (self.rate_hz * self.dt)
        if ratio < 0.999 or abs(ratio - round(ratio)) > 1e-6:
            raise ConfigError(
                f"tick period 1/{self.rate_hz} s must be a whole multiple of dt={self.dt} s (ratio is {ratio:.4f})"
            )
        if not 1 <= self.telemetry_rate_hz <= self.rate_hz:
            raise ConfigError(f"telemetry rate must be 1..{self.rate_hz} Hz, got {self.telemetry_rate_hz}")
        if self.watchdog_ms <= 0 or self.crouch_after_ms < 0:
            raise ConfigError("watchdog must be > 0 ms and the crouch delay >= 0 ms")
        if self.max_late_us < 0 or self.max_future_us <= 0 or self.buffer_depth < 2:
            raise ConfigError("max_late_us >= 0, max_future_us > 0 and buffer_depth >= 2 are required")
        if not self.resume_speed > 0 or self.resume_blend_min_us <= 0:
            raise ConfigError("resume_speed must be > 0 rad/s and resume_blend_min_us > 0")
        kernel_choice(self.kernel)
        return self
