"""The import graph of the source tree: no import circles, and the layers of DEVELOPERS.md.

Layers: ``protocol`` imports none of the other three, ``robots`` only ``protocol``, ``host`` and
``firmware_sim`` ``protocol`` and ``robots`` (never each other); inside ``host`` only the CLI
(``host.cli``, ``host.commands``, ``host.__main__``, and ``host.cli_reference``, which documents it)
imports the commands, so evaluation, runs and the shell never reach up into them; and the runtime path
(shell, LLM clients, motion, link, runtime, runs, both ends' packages) never imports the tooling
(``host.tools``: vcan, fuzz, eval) or the fixtures (``host.testing``, ``protocol.testing``).

The graph is built from the source with :mod:`ast` (nothing is imported): one node per module of
``host/``, ``firmware_sim/``, ``protocol/`` and ``robots/`` (a package is its ``__init__``), one arrow per
import statement anywhere in a module, function bodies and ``if TYPE_CHECKING:`` blocks included (a
circle that exists only for type hints is still a circle: a ``typing.Protocol`` breaks it). ``from P import
name`` is an arrow to ``P.name`` when that is a module, else to ``P``. Circles are the strongly connected
components of more than one module (Tarjan's algorithm, iterative) and modules importing themselves.
A circle that must stay is listed in ``ALLOWED`` with its reason (none today).
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("host", "firmware_sim", "protocol", "robots")

#: circles left on purpose, as frozensets of module names -> why
ALLOWED: dict[frozenset[str], str] = {}


def module_files(root: Path = ROOT) -> dict[str, Path]:
    """Module name -> source file for every module of :data:`PACKAGES` (``pkg/__init__.py`` is ``pkg``)."""
    out: dict[str, Path] = {}
    for pkg in PACKAGES:
        for path in sorted((root / pkg).rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = path
    return out


def _imported(node: ast.Import | ast.ImportFrom, module: str, is_package: bool) -> Iterator[str]:
    """The modules one import statement names (absolute; relative imports resolved)."""
    if isinstance(node, ast.Import):
        yield from (a.name for a in node.names)
        return
    base = node.module or ""
    if node.level:
        here = module.split(".") if is_package else module.split(".")[:-1]
        here = here[: len(here) - (node.level - 1)]
        base = ".".join(here + ([base] if base else []))
    yield base
    for a in node.names:
        yield f"{base}.{a.name}"


def import_graph(root: Path = ROOT) -> dict[str, set[str]]:
    """Module -> the tree's modules it imports (see the module docstring for what counts)."""
    files = module_files(root)
    graph: dict[str, set[str]] = {m: set() for m in files}
    for mod, path in files.items():
        is_package = path.name == "__init__.py"
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            names = list(_imported(node, mod, is_package))
            if isinstance(node, ast.ImportFrom):
                # ``from P import a, b``: P.a where it is a module, else P itself
                base, subs = names[0], names[1:]
                targets = [s for s in subs if s in files]
                if len(targets) < len(subs):
                    targets.append(base)
            else:
                targets = names
            graph[mod].update(t for t in targets if t in files and t != mod)
    return graph


def circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module, each sorted (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    counter = 0
    for start in sorted(graph):
        if start in index:
            continue
        work: list[tuple[str, Iterator[str]]] = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp: list[str] = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        found.append(sorted(comp))
    return sorted(found)


def test_the_graph_sees_known_arrows() -> None:
    """The builder itself: arrows it must find (absolute, relative, submodule and TYPE_CHECKING imports)."""
    g = import_graph()
    assert "protocol.messages" in g["protocol.codec"]
    assert "firmware_sim.board" in g["firmware_sim.server"]
    assert "host.link.client" in g["host.link"]  # the package re-exports BoardClient


def test_circles_found_by_the_builder() -> None:
    g = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a", "e"}, "e": {"d"}, "f": set()}
    assert circles(g) == [["a", "b", "c"], ["d", "e"]]


def test_no_import_circles() -> None:
    left = [c for c in circles(import_graph()) if frozenset(c) not in ALLOWED]
    assert not left, "import circles:\n" + "\n".join(" <-> ".join(c) for c in left)


def test_host_and_firmware_sim_never_import_each_other() -> None:
    bad = [f"{m} imports {t}" for m, ts in import_graph().items() for t in sorted(ts)
           if {m.split(".")[0], t.split(".")[0]} == {"host", "firmware_sim"}]
    assert not bad, "\n".join(bad)


#: package -> the packages of the tree it may import (DEVELOPERS.md, "Layout and import direction")
MAY_IMPORT: dict[str, frozenset[str]] = {
    "protocol": frozenset({"protocol"}),
    "robots": frozenset({"robots", "protocol"}),
    "firmware_sim": frozenset({"firmware_sim", "protocol", "robots"}),
    "host": frozenset({"host", "protocol", "robots"}),
}
#: the host's command line: the only modules that import ``host.cli`` or ``host.commands``
CLI = ("host.cli", "host.commands", "host.__main__", "host.cli_reference")


def _within(module: str, prefixes: tuple[str, ...]) -> bool:
    return any(module == p or module.startswith(p + ".") for p in prefixes)


def test_packages_import_only_their_layers() -> None:
    bad = [f"{m} imports {t}" for m, ts in import_graph().items() for t in sorted(ts)
           if t.split(".")[0] not in MAY_IMPORT[m.split(".")[0]]]
    assert not bad, "\n".join(bad)


def test_only_the_cli_imports_the_commands() -> None:
    g = import_graph()  # (host.cli imports its commands by name, with importlib: no arrows)
    bad = [f"{m} imports {t}" for m, ts in g.items() for t in sorted(ts)
           if _within(t, ("host.cli", "host.commands")) and not _within(m, CLI)]
    assert not bad, "\n".join(bad)


#: the runtime path: what a run goes through from the LLM's text to the board and back
RUNTIME = ("host.shell", "host.ghost", "host.motion", "host.link", "host.runtime", "host.run", "host.speech",
           "host.mounts", "host.chat", "host.mcp_server", "host.calibration", "protocol", "robots", "firmware_sim")
#: tooling and fixtures, kept off the runtime path
TOOLING = ("host.tools", "host.testing", "protocol.testing")


def test_the_runtime_path_never_imports_tooling_or_fixtures() -> None:
    g = import_graph()
    bad = [f"{m} imports {t}" for m, ts in g.items() for t in sorted(ts)
           if _within(t, TOOLING) and _within(m, RUNTIME) and not _within(m, TOOLING)]
    assert not bad, "\n".join(bad)
    assert any(_within(m, ("host.tools",)) for m in g), "host.tools not found: the check would pass vacuously"
