"""A safety policy the shell enforces before any call is dispatched (``--policy FILE``, TOML).

Example (every table optional)::

    [functions]
    allow = ["head_act", "face_emo", "run_distance", "rotate", "speak"]   # absent: all allowed
    deny = ["push_up"]

    [params.run_distance]                 # bounds tighter than the robot's
    distance = { min = -50, max = 50 }

    [budget.run_distance]                 # a motion budget over a sliding window
    param = "distance"                    # sum of |distance| (defaults count when omitted) ...
    max = 100                             # ... at most 100 per window
    max_calls = 5                         # and at most 5 calls per window
    window_s = 60                         # seconds on the run clock (default 60)

    [events]                              # what a run does per world event (read by host.run.events)
    fall = "interrupt"                    # "ignore" | "note" | "interrupt"
    stall = "note"

A refused call fails with ``refused by policy: ...``: the scheduler records it on the timeline and
reports it as an error observation for the LLM's next turn; nothing reaches the link. The budget
ledger lives in the :class:`Policy` object, so it spans turns of one session. Errors in the file
raise :class:`PolicyError` naming the file and the key.
"""

from __future__ import annotations

import inspect
import math
import tomllib
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from host.bounded_read import MAX_POLICY, InputTooLarge, read_capped
from host.shell.types import FunctionSpec

__all__ = ["Budget", "Policy", "PolicyError"]


class PolicyError(ValueError):
    """A policy file that cannot be used, or a call the policy refuses (message says why)."""


def _number(v: Any, key: str) -> float:
    """A TOML number (int or float, not bool) as float; :class:`PolicyError` naming ``key`` otherwise."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or math.isnan(v):
        raise PolicyError(f"{key} must be a number, got {v!r}")
    return float(v)


@dataclass
class Budget:
    """At most ``max`` summed |param| and ``max_calls`` calls of one function per ``window_s`` seconds."""

    param: str | None = None
    max: float | None = None
    max_calls: int | None = None
    window_s: float = 60.0
    ledger: deque[tuple[float, float]] = field(default_factory=deque)  # (time, amount)


@dataclass
class Policy:
    """Allowed functions, parameter bounds and motion budgets; see the module docstring."""

    allow: frozenset[str] | None = None
    deny: frozenset[str] = frozenset()
    bounds: dict[str, dict[str, tuple[float, float]]] = field(default_factory=dict)
    budgets: dict[str, Budget] = field(default_factory=dict)
    refused: int = 0

    @classmethod
    def load(cls, path: str | Path, known: dict[str, frozenset[str]] | None = None) -> Policy:
        """Read a TOML policy; :class:`PolicyError` with the file and key on any problem (with ``known``,
        function name -> parameter names, also a name that matches nothing: :meth:`check_names`)."""
        try:
            doc = tomllib.loads(read_capped(path, MAX_POLICY).decode("utf-8"))
        except InputTooLarge as e:
            raise PolicyError(f"policy {path}: {e}") from None
        except OSError as e:
            raise PolicyError(f"cannot read policy {path}: {e.strerror or e}") from None
        except UnicodeDecodeError as e:
            raise PolicyError(f"policy {path} is not UTF-8 text: {e.reason} at byte {e.start}") from None
        except tomllib.TOMLDecodeError as e:
            raise PolicyError(f"policy {path} is not valid TOML: {e}") from None
        try:
            policy = cls.from_dict(doc)
            if known is not None:
                policy.check_names(known)
            return policy
        except PolicyError as e:
            raise PolicyError(f"policy {path}: {e}") from None

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Policy:
        unknown = set(doc) - {"functions", "params", "budget", "events"}  # [events]: host.run.events reads it
        if unknown:
            raise PolicyError(f"unknown table(s) {sorted(unknown)}; expected functions, params, budget, events")
        fns = doc.get("functions", {})
        extra = set(fns) - {"allow", "deny"} if isinstance(fns, dict) else set()
        if extra:
            raise PolicyError(f"functions: unknown key(s) {sorted(extra)}; expected allow, deny")
        allow = fns.get("allow")
        deny = fns.get("deny", [])
        for key, v in (("functions.allow", allow), ("functions.deny", deny)):
            if v is not None and not (isinstance(v, list) and all(isinstance(x, str) for x in v)):
                raise PolicyError(f"{key} must be a list of function names")
        bounds: dict[str, dict[str, tuple[float, float]]] = {}
        for fn, params in doc.get("params", {}).items():
            if not isinstance(params, dict):
                raise PolicyError(f"params.{fn} must be a table of parameter bounds")
            for p, b in params.items():
                if not isinstance(b, dict) or set(b) - {"min", "max"} or not b:
                    raise PolicyError(f"params.{fn}.{p} must be a table with min and/or max")
                lo, hi = _number(b.get("min", -math.inf), f"params.{fn}.{p}.min"), _number(b.get("max", math.inf), f"params.{fn}.{p}.max")
                if lo > hi:
                    raise PolicyError(f"params.{fn}.{p}: min {lo:g} > max {hi:g}")
                bounds.setdefault(fn, {})[p] = (lo, hi)
        budgets: dict[str, Budget] = {}
        for fn, b in doc.get("budget", {}).items():
            if not isinstance(b, dict):
                raise PolicyError(f"budget.{fn} must be a table")
            extra = set(b) - {"param", "max", "max_calls", "window_s"}
            if extra:
                raise PolicyError(f"budget.{fn}: unknown key(s) {sorted(extra)}")
            param = b.get("param")
            if param is not None and not isinstance(param, str):
                raise PolicyError(f"budget.{fn}.param must be a parameter name (a string)")
            bmax = None if b.get("max") is None else _number(b["max"], f"budget.{fn}.max")
            calls = b.get("max_calls")
            if calls is not None and (not isinstance(calls, int) or isinstance(calls, bool) or calls < 1):
                raise PolicyError(f"budget.{fn}.max_calls must be a whole number >= 1, got {calls!r}")
            bud = Budget(param, bmax, calls, _number(b.get("window_s", 60.0), f"budget.{fn}.window_s"))
            if (bud.param is None) != (bud.max is None):
                raise PolicyError(f"budget.{fn}: param and max go together")
            if bud.max is None and bud.max_calls is None:
                raise PolicyError(f"budget.{fn}: give max (with param) and/or max_calls")
            if bud.window_s <= 0:
                raise PolicyError(f"budget.{fn}.window_s must be > 0")
            budgets[fn] = bud
        return cls(frozenset(allow) if allow is not None else None, frozenset(deny), bounds, budgets)

    def check_names(self, known: dict[str, frozenset[str]]) -> None:
        """Refuse names that match nothing: a misspelt function or parameter would silently switch a
        limit off. ``known`` maps every function name (aliases included) to its parameter names;
        raises :class:`PolicyError` naming the key and, when one is close, what was meant."""
        import difflib

        def hint(name: str, pool: Any) -> str:
            close = difflib.get_close_matches(name, list(pool), n=1)
            return f"; did you mean {close[0]}?" if close else ""

        where: list[tuple[str, str]] = [("functions.allow", n) for n in sorted(self.allow or ())]
        where += [("functions.deny", n) for n in sorted(self.deny)]
        where += [(f"params.{fn}", fn) for fn in self.bounds] + [(f"budget.{fn}", fn) for fn in self.budgets]
        for key, fn in where:
            if fn not in known:
                raise PolicyError(f"{key}: no function {fn!r}{hint(fn, known)}")
        for fn, params in self.bounds.items():
            for p in params:
                if p not in known[fn]:
                    raise PolicyError(f"params.{fn}.{p}: <{fn}> has no parameter {p!r}{hint(p, known[fn])}")
        for fn, bud in self.budgets.items():
            if bud.param is not None and bud.param not in known[fn]:
                raise PolicyError(f"budget.{fn}.param: <{fn}> has no parameter {bud.param!r}{hint(bud.param, known[fn])}")

    def check(self, spec: FunctionSpec, args: dict[str, Any], now_s: float) -> None:
        """Raise :class:`PolicyError` if the call is refused; otherwise charge its budget at ``now_s``."""
        names = {spec.name, *spec.aliases}
        if spec.speech and self.allow is None and not (names & self.deny):
            return
        if names & self.deny or (self.allow is not None and not names & self.allow):
            self.refused += 1
            raise PolicyError(f"refused by policy: <{spec.name}> is not allowed")
        full = self._with_defaults(spec, args)
        for fn in names:
            for p, (lo, hi) in self.bounds.get(fn, {}).items():
                v = full.get(p)
                if isinstance(v, (int, float)) and not isinstance(v, bool) and not lo <= v <= hi:
                    self.refused += 1
                    raise PolicyError(f"refused by policy: <{spec.name}> {p}={v:g} is outside [{lo:g}, {hi:g}]")
        bud = next((self.budgets[n] for n in names if n in self.budgets), None)
        if bud is None:
            return
        while bud.ledger and bud.ledger[0][0] <= now_s - bud.window_s:
            bud.ledger.popleft()
        amount = 0.0
        if bud.param is not None:
            v = full.get(bud.param, 0.0)
            amount = abs(float(v)) if isinstance(v, (int, float)) else 0.0
        if bud.max_calls is not None and len(bud.ledger) + 1 > bud.max_calls:
            self.refused += 1
            raise PolicyError(
                f"refused by policy: <{spec.name}> budget of {bud.max_calls} call(s) per {bud.window_s:g} s is used up"
            )
        if bud.max is not None:
            used = sum(a for _, a in bud.ledger)
            if used + amount > bud.max:
                self.refused += 1
                raise PolicyError(
                    f"refused by policy: <{spec.name}> {bud.param}={amount:g} would exceed the budget of "
                    f"{bud.max:g} per {bud.window_s:g} s ({used:g} used)"
                )
        bud.ledger.append((now_s, amount))

    @staticmethod
    def _with_defaults(spec: FunctionSpec, args: dict[str, Any]) -> dict[str, Any]:
        full = {p.name: p.default for p in spec.params if p.default is not inspect.Parameter.empty}
        full.update(args)
        return full
