"""Run a one-input function under atheris (libFuzzer); used by every host-side target's ``__main__``.

:func:`instrument_only` narrows atheris' import hook to the modules a target tests: ``atheris.
instrument_imports(include=["protocol.can"])`` takes only the *top-level* package of each name
(atheris 2.x, ``import_hook.instrument_imports``), so it instruments every ``protocol`` module the
import pulls in (the codec, the messages, ...), and every instrumented line costs a coverage and a
comparison hook per execution. :func:`instrument_only` passes the package and excludes each of its
other modules (found on disk, nothing is imported to list them).

``firmware_sim.fuzz`` carries a copy of these few lines because the board never imports the host.
"""

from __future__ import annotations

import importlib.util
import pkgutil
import sys
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager

__all__ = ["instrument_only", "package_modules", "run_atheris"]


def package_modules(package: str) -> list[str]:
    """Every module and subpackage name under the top-level ``package`` (read from its folders)."""
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        return [package]
    out = [package]
    stack = [(package, list(spec.submodule_search_locations))]
    while stack:
        prefix, paths = stack.pop()
        for info in pkgutil.iter_modules(paths):
            name = f"{prefix}.{info.name}"
            out.append(name)
            if info.ispkg:
                stack.append((name, [f"{p}/{info.name}" for p in paths]))
    return out


@contextmanager
def instrument_only(modules: Sequence[str]) -> Iterator[None]:
    """Instrument, among the modules imported in the ``with`` block, exactly ``modules`` and their submodules.

    A module already imported stays as it is (import the code under test first, inside the block).
    """
    import atheris  # type: ignore[import-not-found,unused-ignore]

    wanted = tuple(modules)
    tops = sorted({m.split(".")[0] for m in wanted})
    others = [  # parent packages too: their ``__init__`` is not under test
        name for top in tops for name in package_modules(top)
        if not any(name == w or name.startswith(w + ".") for w in wanted)
    ]
    with atheris.instrument_imports(include=tops, exclude=others):
        yield


def run_atheris(load: Callable[[bool], Callable[[bytes], None]], module: str) -> None:
    """``load(True)`` imports the code under test inside :func:`instrument_only`; then fuzz.

    ``argv[0]`` becomes ``python -m MODULE``: libFuzzer's ``-fork``/``-jobs`` modes re-run it through
    the shell, and a module's ``.py`` path is not executable.
    """
    import atheris  # type: ignore[import-not-found,unused-ignore]

    one_input = load(True)
    atheris.Setup([f"{sys.executable} -m {module}", *sys.argv[1:]], one_input)
    atheris.Fuzz()
