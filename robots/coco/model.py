"""CoCo's compiled MuJoCo model (the generic :mod:`robots.model` for CoCo; kept for CoCo's own tools)."""

from __future__ import annotations

from robots.coco import ROBOT, ServoTable
from robots.model import RobotModel

__all__ = ["CocoModel", "load_model"]

FOOT_SITES = ROBOT.base.feet
CocoModel = RobotModel


def load_model(table: ServoTable | None = None, scene: str = "empty") -> RobotModel:
    """Compile CoCo's MJCF (plus the objects of ``scene``) with every servo resolved."""
    from robots.model import load_model as _load

    return _load(ROBOT, scene)
