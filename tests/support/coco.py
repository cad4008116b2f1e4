"""CoCo's registry for shell tests: :func:`host.runtime.binding.robot_registry` with CoCo mounted."""

from __future__ import annotations

from typing import Any

from host.runtime.binding import function_params as _function_params
from host.runtime.binding import robot_registry
from host.shell.registry import Registry
from robots.coco import ROBOT


def coco_registry(performer: Any, vocabulary: str = "paper") -> Registry:
    """A registry with CoCo mounted: ``vocabulary`` visible, the other hidden."""
    return robot_registry(ROBOT, performer, vocabulary)


def function_params() -> dict[str, frozenset[str]]:
    """Every function CoCo's shell accepts -> its parameter names."""
    return _function_params(ROBOT)
