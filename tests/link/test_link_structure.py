"""The link client is made of parts (issue 44): no class in host/link over 300 lines, no mixin stubs.

``BoardClient`` inherited four mixins whose bodies reached the session's private methods through
stubs raising NotImplementedError (773 lines, 73 methods in one object). It is now a facade holding
parts that know each other through narrow Protocols; these pin that shape and the facade's
read-through attributes.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import host.link
from host.link import BoardClient

LINK = Path(host.link.__file__).parent
MAX_CLASS_LINES = 300


def _classes() -> list[tuple[str, int]]:
    spans = []
    for path in sorted(LINK.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ClassDef):
                assert node.end_lineno is not None
                spans.append((f"{path.relative_to(LINK)}:{node.name}", node.end_lineno - node.lineno + 1))
    return spans


def test_no_class_in_host_link_is_over_300_lines() -> None:
    big = [(name, n) for name, n in _classes() if n > MAX_CLASS_LINES]
    assert not big, f"classes over {MAX_CLASS_LINES} lines: {big}"


def _raises_not_implemented(node: ast.AST) -> bool:
    if not isinstance(node, ast.Raise) or node.exc is None:
        return False
    exc = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
    return isinstance(exc, ast.Name) and exc.id == "NotImplementedError"


def test_no_part_reaches_another_through_not_implemented_stubs() -> None:
    stubs = [f"{p.relative_to(LINK)}:{node.lineno}" for p in sorted(LINK.rglob("*.py"))
             for node in ast.walk(ast.parse(p.read_text())) if _raises_not_implemented(node)]
    assert not stubs, f"NotImplementedError stubs at {stubs}"


def test_the_client_is_a_facade_not_a_stack_of_mixins() -> None:
    assert BoardClient.__bases__ == (object,)


def test_the_facades_attributes_are_its_parts() -> None:
    c = BoardClient("/dev/null", reconnect=False)
    assert c.stats is c.session.stats and c.requests is c.session.requests and c.on_received is c.receiver.on_received
    c.keepalive = False  # writable: it is the supervisor's
    assert c.supervisor.keepalive is False and c.keepalive is False
    with pytest.raises(AttributeError):
        c.caps = None  # type: ignore[misc]  # read-only: the handshake sets it on the session
    assert c.port_name == c.session.port_name == "/dev/null" and not c.connected
