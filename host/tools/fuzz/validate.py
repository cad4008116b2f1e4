"""An independent check that a typed value satisfies a shell parameter annotation.

Used by the ``shell`` fuzz target as the oracle for "every dispatched call passed validation": it
re-derives the rules from the annotation (``Annotated[..., Range]``, ``Literal``, unions, ``bool``,
``int``, finite ``float``, ``str``, ``Enum``) instead of calling the mapper it checks.
"""

from __future__ import annotations

import enum
import math
import types
import typing
from typing import Annotated, Any, Literal, Union

from host.shell.types import as_range

__all__ = ["conforms"]


def conforms(value: Any, annotation: Any) -> bool:
    """True when ``value`` is a legal argument for a parameter annotated ``annotation``."""
    origin = typing.get_origin(annotation)
    if origin is Annotated:
        base, *meta = typing.get_args(annotation)
        if not conforms(value, base):
            return False
        for m in meta:
            rng = as_range(m)
            if rng is not None and value is not None and not (rng.lo <= value <= rng.hi):
                return False
        return True
    if origin is Literal:
        return any(value == o and type(value) is type(o) for o in typing.get_args(annotation))
    if origin in (Union, types.UnionType):
        return any(conforms(value, a) for a in typing.get_args(annotation))
    if annotation is type(None):
        return value is None
    if annotation is Any:
        return True
    if annotation is str:
        return isinstance(value, str)
    if annotation is bool:
        return isinstance(value, bool)
    if annotation is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if annotation is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        return isinstance(value, annotation)
    return False
