"""Hardware conditions injected into the plant: what real servo buses do that a clean model does not.

:class:`Conditions` is plain data, given to :class:`~firmware_sim.plant.world.World` (the servo
side: offsets, reversal, model numbers, errors) and read from there by
:class:`~firmware_sim.plant.bus.PlantBus` (the wire side: missing, duplicate, corrupt). The command
line's spellings (``--offset 3=120``, ``--error 2=overload@1.5`` ...) are parsed by the
``parse_*`` helpers; a malformed value raises :class:`ValueError` naming it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from firmware_sim.plant.servo import Fault

__all__ = ["Conditions", "FAULT_NAMES", "ServoError", "parse_error", "parse_id", "parse_id_int"]

#: ``--error`` spellings
FAULT_NAMES: dict[str, int] = {"overload": Fault.OVERLOAD, "overheat": Fault.OVERHEAT, "voltage": Fault.VOLTAGE}


@dataclass(frozen=True)
class ServoError:
    """Servo ``id`` reports ``fault`` from world time ``at_us`` on (and, for overload/overheat, its
    torque goes off)."""

    id: int
    fault: int  # Fault bits
    at_us: int


@dataclass(frozen=True)
class Conditions:
    """Injected conditions (all empty: a healthy, calibrated bus).

    ``offsets``: servo id -> steps added to its raw position (a horn mounted off centre, an
    uncalibrated servo); ``reversed``: ids whose raw direction is the opposite of the servo table's
    (``raw = STEP_CENTRE + offset + direction * table_direction * round((q - neutral) / step)``,
    direction -1, as :mod:`robots.hardware` defines); ``models``: id -> the model number it reports;
    ``missing``: ids that never answer; ``duplicate``: ids two devices answer to (their status
    packets collide on the half-duplex line); ``errors``: timed hardware errors; ``corrupt``: the
    probability (0..1) that a status packet's checksum/CRC is broken, drawn from ``seed``.
    """

    offsets: dict[int, int] = field(default_factory=dict)
    reversed: frozenset[int] = frozenset()
    models: dict[int, int] = field(default_factory=dict)
    missing: frozenset[int] = frozenset()
    duplicate: frozenset[int] = frozenset()
    errors: tuple[ServoError, ...] = ()
    corrupt: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if not 0.0 <= self.corrupt <= 1.0:
            raise ValueError(f"corrupt must be a probability in 0..1, got {self.corrupt}")


def parse_id(text: str) -> int:
    """``"3"`` -> 3 (a bus id 0..252)."""
    try:
        v = int(text, 0)
    except ValueError:
        raise ValueError(f"not a servo id: {text!r}") from None
    if not 0 <= v <= 252:
        raise ValueError(f"servo id must be 0..252, got {v}")
    return v


def parse_id_int(text: str) -> tuple[int, int]:
    """``"3=-120"`` -> (3, -120)."""
    sid, sep, value = text.partition("=")
    if not sep:
        raise ValueError(f"expected ID=NUMBER, got {text!r}")
    try:
        return parse_id(sid), int(value, 0)
    except ValueError as e:
        raise ValueError(f"expected ID=NUMBER, got {text!r} ({e})") from None


def parse_error(text: str) -> ServoError:
    """``"3=overload@1.5"`` -> ServoError(3, OVERLOAD, 1_500_000); ``@SECONDS`` defaults to 0."""
    sid, sep, rest = text.partition("=")
    kind, _, at = rest.partition("@")
    if not sep or kind not in FAULT_NAMES:
        raise ValueError(f"expected ID={'|'.join(FAULT_NAMES)}@SECONDS, got {text!r}")
    try:
        seconds = float(at) if at else 0.0
    except ValueError:
        raise ValueError(f"not a time in seconds: {at!r} in {text!r}") from None
    if seconds < 0:
        raise ValueError(f"the time must not be negative: {text!r}")
    return ServoError(parse_id(sid), FAULT_NAMES[kind], int(round(seconds * 1e6)))
