"""Fuzz target ``bus-dxl2``: see :mod:`firmware_sim.servobus.fuzz`."""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["load"]


def load(instrument: bool = False) -> Callable[[bytes], None]:
    """The one-input function (:func:`firmware_sim.servobus.fuzz.load` for ``dxl2``)."""
    from firmware_sim.servobus.fuzz import load as load_target

    return load_target("dxl2", instrument)


if __name__ == "__main__":
    from firmware_sim.servobus.fuzz import main

    main("dxl2")
