"""Attributes of a facade that are one of its parts' own: ``caps = PartAttr[Caps | None]("session.caps")``.

:class:`host.link.client.BoardClient` holds its parts (the session, the board clock, the receive
path, ...) as attributes and shows their state under its own names. At run time a :class:`PartAttr`
is a ``property`` whose getter is :func:`operator.attrgetter` of the dotted path (no Python frame per
read: as fast as a hand-written property, ~90 ns); a :class:`WritablePartAttr` also sets the part's
attribute (setting a read-only one raises AttributeError). For mypy both are descriptors typed by
their parameter (what the attribute holds), so reads and writes are checked like the part's own.
"""

from __future__ import annotations

import operator
from typing import TYPE_CHECKING, Any, Generic, TypeVar, overload

__all__ = ["PartAttr", "WritablePartAttr"]

T = TypeVar("T")

if TYPE_CHECKING:

    class PartAttr(Generic[T]):
        """A read-only attribute that is ``<part>.<name>`` of the instance."""

        def __init__(self, path: str) -> None: ...
        @overload
        def __get__(self, obj: None, owner: type | None = None) -> PartAttr[T]: ...
        @overload
        def __get__(self, obj: object, owner: type | None = None) -> T: ...
        def __get__(self, obj: object, owner: type | None = None) -> Any: ...

    class WritablePartAttr(PartAttr[T]):
        """A :class:`PartAttr` that may be set (it sets the part's attribute)."""

        def __set__(self, obj: object, value: T) -> None: ...

else:

    class PartAttr:
        """A read-only attribute that is ``<part>.<name>`` of the instance: a ``property`` (module docstring)."""

        def __class_getitem__(cls, item: Any) -> type:
            return cls

        def __new__(cls, path: str) -> property:
            return property(operator.attrgetter(path), doc=f"``{path}``")

    class WritablePartAttr(PartAttr):
        """A :class:`PartAttr` that may be set (it sets the part's attribute)."""

        def __new__(cls, path: str) -> property:
            part, name = path.rsplit(".", 1)
            get_part = operator.attrgetter(part)

            def set_(obj: object, value: object) -> None:
                setattr(get_part(obj), name, value)

            return property(operator.attrgetter(path), set_, doc=f"``{path}``")
