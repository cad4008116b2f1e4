"""Where things are in an MJCF: every element with its attributes, file and line, ``<include>`` followed.

MuJoCo's compiler knows each element's place but does not report it for a compiled model, so the
robot tools read the XML once more to point at ``file:line``. Python's expat binding gives each
element's line (``xml.etree`` drops line numbers), which is all this needs; writing it by hand is
these forty lines, not a parser.

:func:`index_mjcf` returns :class:`MjcfIndex`: the elements in document order with includes expanded
in place (the order MuJoCo compiles them in), each an :class:`Element` (``tag``, ``attrs``,
``file``, ``line``, ``parent`` tag). An include's path is resolved against the main model file's
folder (MuJoCo's rule), then against the including file's folder. A file that cannot be read or is
not well-formed XML raises :class:`robots.description.RobotDataError` with file:line.
"""

from __future__ import annotations

import xml.parsers.expat
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from robots.datatypes import RobotDataError

__all__ = ["Element", "MjcfIndex", "index_mjcf"]

#: includes nested deeper than this are refused (a cycle would otherwise never end)
MAX_INCLUDE_DEPTH = 16


@dataclass(frozen=True)
class Element:
    """One XML element: tag, attributes, the file and 1-based line it starts on, its parent's tag."""

    tag: str
    attrs: dict[str, str]
    file: Path
    line: int
    parent: str

    @property
    def where(self) -> str:
        """``file:line`` for messages."""
        return f"{self.file}:{self.line}"


@dataclass
class MjcfIndex:
    """The elements of an MJCF and its includes, in compile order; ``files``: every XML file read."""

    main: Path
    elements: list[Element] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)

    def __iter__(self) -> Iterator[Element]:
        return iter(self.elements)

    def named(self, tag: str, name: str) -> Element | None:
        """The first ``<tag name="name">`` (None when absent)."""
        for e in self.elements:
            if e.tag == tag and e.attrs.get("name") == name:
                return e
        return None

    def children_of(self, parent: str) -> list[Element]:
        """Every element whose parent is a ``<parent>`` element, in order (e.g. the actuators)."""
        return [e for e in self.elements if e.parent == parent]

    def first(self, tag: str) -> Element | None:
        return next((e for e in self.elements if e.tag == tag), None)


def index_mjcf(path: Path) -> MjcfIndex:
    """Read ``path`` and every file it includes (see the module docstring)."""
    path = Path(path).resolve()
    index = MjcfIndex(path)
    _read(path, index, parents=[], depth=0)
    return index


def _read(path: Path, index: MjcfIndex, parents: list[str], depth: int) -> None:
    try:
        data = path.read_bytes()
    except OSError as e:
        raise RobotDataError(f"{path}: cannot read it ({e.strerror})") from None
    index.files.append(path)
    parser = xml.parsers.expat.ParserCreate()
    stack = list(parents)
    top = len(parents)
    includes: list[tuple[Element, list[str], int]] = []  # (include element, parents, position in elements)

    def start(tag: str, attrs: dict[str, str]) -> None:
        if depth > 0 and len(stack) == top and tag == "mujoco":  # an included file's root: transparent
            stack.append("")
            return
        parent = next((p for p in reversed(stack) if p), "")
        el = Element(tag, dict(attrs), path, parser.CurrentLineNumber, parent)
        if tag == "include":
            includes.append((el, [p for p in stack if p], len(index.elements)))
        index.elements.append(el)
        stack.append(tag)

    def end(tag: str) -> None:
        stack.pop()

    parser.StartElementHandler = start
    parser.EndElementHandler = end
    try:
        parser.Parse(data, True)
    except xml.parsers.expat.ExpatError as e:
        raise RobotDataError(f"{path}:{e.lineno}: not well-formed XML ({xml.parsers.expat.ErrorString(e.code)})") \
            from None
    # expand includes in place, last first so earlier positions stay valid
    for el, inc_parents, pos in reversed(includes):
        name = el.attrs.get("file", "")
        if not name:
            raise RobotDataError(f"{el.where}: <include> needs file=\"...\"")
        if depth + 1 > MAX_INCLUDE_DEPTH:
            raise RobotDataError(f"{el.where}: includes nest deeper than {MAX_INCLUDE_DEPTH} (a cycle?)")
        target = resolve_include(index.main, path, name)
        if target is None:
            where = index.main.name if path == index.main else f"{index.main.name} or {path.name}"
            raise RobotDataError(f"{el.where}: included file {name!r} not found (next to {where})")
        sub = MjcfIndex(index.main)
        _read(target, sub, inc_parents, depth + 1)
        index.elements[pos + 1:pos + 1] = sub.elements
        index.files.extend(f for f in sub.files if f not in index.files)


def resolve_include(main: Path, including: Path, name: str) -> Path | None:
    """The file ``<include file=name>`` means: absolute, else next to the main model, else next to the
    including file (None when none exists)."""
    p = Path(name)
    for candidate in ((p,) if p.is_absolute() else (main.parent / p, including.parent / p)):
        if candidate.is_file():
            return candidate.resolve()
    return None
