"""The effort each servo's actuator can apply at most: what "effort saturated" means for a stall.

A stall event (:mod:`host.run.events`) needs a servo pushing at its limit. The limit of servo ``i``
is ``(lo, hi)`` in N*m (TELEMETRY's ``efforts`` units), taken from, first found:

1. its MJCF actuator's ``forcerange`` when the actuator is force-limited (``forcelimited`` true, or
   ``auto``/absent with a ``forcerange``: MuJoCo's autolimits), the attribute on the actuator or
   inherited through its ``class`` and the nested ``<default>`` classes (``main`` when it names none);
2. the servo table's ``stall_torque_nm`` (``[model]``), as ``(-t, t)``;
3. none (``None``): the servo never counts as saturated, so it gets no stall event.

Read from the XML (``<include>`` followed, :func:`robots.mjcf_index.resolve_include`), not by
compiling the model: importing MuJoCo costs the host ~0.2 s (robots.mjcf_check_cache). Every
actuator element of ``<actuator>`` counts (``position``, ``motor``, ``general`` ...); in a
``<default>`` their attributes are one actuator default, as in MuJoCo. An MJCF that cannot be read
gives the table's torque for every servo (the robot loader has already checked the MJCF).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING

from robots.mjcf_index import resolve_include

if TYPE_CHECKING:
    from robots.datatypes import RobotData

__all__ = ["EffortLimit", "effort_limits", "mjcf_force_ranges"]

#: (lo, hi) N*m
EffortLimit = tuple[float, float]

_ACTUATORS = frozenset({"general", "motor", "position", "velocity", "intvelocity", "damper", "cylinder", "muscle",
                        "adhesion", "plugin"})
_KEYS = ("forcerange", "forcelimited")
_MAX_DEPTH = 16


def _expand(el: ET.Element, main: Path, here: Path, depth: int) -> None:
    """Replace every ``<include file=...>`` under ``el`` by the included file's children."""
    for i, child in enumerate(list(el)):
        if child.tag == "include" and depth < _MAX_DEPTH:
            target = resolve_include(main, here, child.get("file", ""))
            el.remove(child)
            if target is None:
                continue
            sub = ET.parse(target).getroot()
            _expand(sub, main, target, depth + 1)
            for j, grandchild in enumerate(list(sub)):
                el.insert(i + j, grandchild)
        else:
            _expand(child, main, here, depth)


def _defaults(el: ET.Element, inherited: dict[str, str], out: dict[str, dict[str, str]]) -> None:
    """Class name -> the actuator attributes (:data:`_KEYS`) a ``<default>`` gives, its parents' included."""
    own = dict(inherited)
    for child in el:
        if child.tag in _ACTUATORS:
            own.update({k: v for k, v in child.attrib.items() if k in _KEYS})
    out[el.get("class", "main")] = own
    for child in el:
        if child.tag == "default":
            _defaults(child, own, out)


def _limit(attrs: dict[str, str]) -> EffortLimit | None:
    limited = attrs.get("forcelimited", "auto").strip().lower()
    text = attrs.get("forcerange")
    if limited == "false" or text is None:
        return None
    try:
        lo, hi = (float(x) for x in text.split())
    except ValueError:
        return None
    return (lo, hi) if lo < hi else None


def mjcf_force_ranges(mjcf: Path) -> dict[str, EffortLimit | None]:
    """Actuator name -> its force range (N*m, None when not force-limited) in the MJCF at ``mjcf``.

    Raises OSError / ET.ParseError for a file that cannot be read or parsed."""
    mjcf = Path(mjcf).resolve()
    root = ET.parse(mjcf).getroot()
    _expand(root, mjcf, mjcf, 0)
    classes: dict[str, dict[str, str]] = {}
    for d in root.findall("default"):  # the top-level <default> (class "main") and its nested classes
        _defaults(d, {}, classes)
    out: dict[str, EffortLimit | None] = {}
    for section in root.iter("actuator"):
        for act in section:
            if act.tag not in _ACTUATORS or act.get("name") is None:
                continue
            attrs = dict(classes.get(act.get("class", "main"), classes.get("main", {})))
            attrs.update({k: v for k, v in act.attrib.items() if k in _KEYS})
            out[act.get("name", "")] = _limit(attrs)
    return out


def effort_limits(robot: RobotData) -> tuple[EffortLimit | None, ...]:
    """Per servo (id order): the ``(lo, hi)`` effort limit in N*m, None when unknown (module docstring)."""
    try:
        ranges = mjcf_force_ranges(robot.mjcf)
    except (OSError, ET.ParseError):
        ranges = {}
    torque = robot.servos.model.stall_torque
    table: EffortLimit | None = (-torque, torque) if torque else None
    return tuple(ranges.get(s.actuator) or table for s in robot.servos)
