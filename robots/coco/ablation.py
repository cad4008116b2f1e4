"""CoCo's words for the native-call ablation judge (paper Section 5, the 15 ablation tasks).

The task data (``paper_results.json``) states each task's expected pattern in shorthand atoms
(``rotate{earShake}``, ``headAct(nod, 3s) -> say``); here each atom is a predicate on one
board-measured call of CoCo's vocabularies (duck-typed: ``function``, ``args``, ``start``, ``end``),
for the generic judge in ``host.tools.eval.native``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["ATOMS", "LIFECYCLE_PATTERNS", "call_atom"]


def _arg(c: Any, *names: str) -> Any:
    for n in names:
        if n in c.args:
            return c.args[n]
    return None


def _num(v: Any, default: float = 0.0) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return default


#: pattern atom -> predicate on a call (both of CoCo's vocabularies)
ATOMS: dict[str, Callable[[Any], bool]] = {
    "say": lambda c: c.function in ("speak", "say"),
    "move": lambda c: (c.function in ("run_distance", "move_forward", "spider_run_distance", "creep")
                       and _num(_arg(c, "distance"), 1.0) > 0 and _arg(c, "direction") in (None, "forward"))
    or (c.function == "move_strides" and _arg(c, "direction") in (None, "forward")),
    "backward": lambda c: (c.function in ("run_distance", "spider_run_distance") and _num(_arg(c, "distance"), 0) < 0)
    or (c.function in ("move_strides", "creep") and _arg(c, "direction") == "backward"),
    "rotate": lambda c: c.function in ("rotate", "spider_rotate"),
    "headShake": lambda c: (c.function == "head_act" and _arg(c, "action") == "shake") or c.function == "head_shake",
    "headNod": lambda c: c.function == "head_act" and _arg(c, "action") in ("nod", None),
    "earShake": lambda c: c.function in ("shake_ear", "shake_ears", "ear_swing"),
    "ears": lambda c: c.function in ("shake_ear", "shake_ears", "ear_swing", "ear_state"),
    "smile": lambda c: c.function in ("face_emo", "display_face", "emotion")
    and str(_arg(c, "emo", "face")) in ("happy", "smile", "None", "laugh"),
    "pushUp": lambda c: c.function in ("push_up", "spider_push_up"),
}

#: ``nested lifecycle`` tasks: the pattern each one means (paper Table: lifecycle-scoped termination)
LIFECYCLE_PATTERNS = {
    13: "rotate{earShake}",
    14: "rotate{say}",
    15: "rotate{headShake, earShake}",
}


def call_atom(base: str, args: list[str]) -> tuple[Callable[[Any], bool], Callable[[Any], bool]]:
    """The data's shorthand with arguments (``headAct(nod, 3s)``, ``pushUp(3)``): (predicate, check on the
    measured call). ValueError for an unknown shorthand."""
    if base == "headAct":
        action = args[0] if args else "nod"
        secs = next((float(a[:-1]) for a in args if a.endswith("s")), None)
        return (ATOMS["headNod" if action == "nod" else "headShake"],
                lambda c: secs is None or abs((c.end - c.start) - secs) <= 0.6 * secs)
    if base == "pushUp":
        times = int(args[0]) if args else None
        return (ATOMS["pushUp"], lambda c: times is None or _arg(c, "times") in (None, times, str(times))
                or _num(_arg(c, "times")) == times)
    raise ValueError(f"unknown pattern call {base!r}")
