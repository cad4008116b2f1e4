"""Run a one-input function under atheris (libFuzzer); used by every host-side target's ``__main__``.

:func:`instrument_only` narrows atheris' import hook to the modules a target tests: ``atheris.
instrument_imports(include=["protocol.can"])`` takes only the *top-level* package of each name
(atheris 2.x, ``import_hook.instrument_imports``), so it instruments every ``protocol`` module the
import pulls in (the codec, the messages, ...), and every instrumented line costs a coverage and a
comparison hook per execution. :func:`instrument_only` passes the package and excludes each of its
other modules (found on disk, nothing is imported to list them).

``firmware_sim.fuzz`` carries a copy of these few lines because the board never imports the host.

:func:`without_hooks` gives a class whose methods run the same source without atheris' hooks: a
target that runs the code under test twice per input to compare (the serial decoder fed in chunks
and whole) needs the coverage of one run only, and an instrumented line costs a few times a plain one.
"""

from __future__ import annotations

import importlib.util
import pkgutil
import sys
import types
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any, TypeVar

__all__ = ["instrument_only", "package_modules", "run_atheris", "without_hooks"]

C = TypeVar("C", bound=type)


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
    Each instrumented code object gets its real stack size (:mod:`host.tools.fuzz.stackdepth`): atheris'
    estimate made every call of a long function allocate a fresh frame chunk.
    """
    import atheris  # type: ignore[import-not-found,unused-ignore]

    wanted = tuple(modules)
    tops = sorted({m.split(".")[0] for m in wanted})
    others = [  # parent packages too: their ``__init__`` is not under test
        name for top in tops for name in package_modules(top)
        if not any(name == w or name.startswith(w + ".") for w in wanted)
    ]
    from atheris import import_hook  # type: ignore[import-not-found,unused-ignore]

    from host.tools.fuzz.stackdepth import fit_stacksize

    patch = import_hook.patch_code

    def patch_and_fit(code: Any, *args: Any, **kwargs: Any) -> Any:
        return fit_stacksize(patch(code, *args, **kwargs))

    import_hook.patch_code = patch_and_fit  # atheris' loaders call it by this name
    try:
        with atheris.instrument_imports(include=tops, exclude=others):
            yield
    finally:
        import_hook.patch_code = patch


def without_hooks(cls: C) -> C:
    """A subclass of ``cls`` whose methods are those of ``cls``'s class body compiled again from the
    module's source file, so without the coverage and comparison hooks atheris patched into them.

    The methods share the module's globals (a helper the module calls, or a name patched in the
    module, is the same object), properties are copied the same way; a method with a closure (e.g.
    ``super()``) is left as inherited. Raises ``LookupError`` if the class body is not found.
    """
    module = sys.modules[cls.__module__]
    path = Path(module.__file__ or "")
    code = compile(path.read_text(encoding="utf-8"), str(path), "exec")
    body = next((c for c in code.co_consts if isinstance(c, types.CodeType) and c.co_name == cls.__name__), None)
    if body is None:
        raise LookupError(f"class {cls.__qualname__} not found at the top level of {path}")
    plain = {(c.co_name, c.co_firstlineno): c for c in body.co_consts if isinstance(c, types.CodeType)}

    def rebuilt(f: Any) -> Any:
        if not isinstance(f, types.FunctionType) or f.__closure__:
            return f
        key = (f.__code__.co_name, f.__code__.co_firstlineno)
        if key not in plain:
            return f
        g = types.FunctionType(plain[key], module.__dict__, f.__name__, f.__defaults__)
        g.__kwdefaults__, g.__qualname__, g.__doc__ = f.__kwdefaults__, f.__qualname__, f.__doc__
        return g

    attrs: dict[str, object] = {"__module__": cls.__module__, "__qualname__": f"{cls.__qualname__}.without_hooks"}
    for name, value in vars(cls).items():
        if isinstance(value, types.FunctionType):
            attrs[name] = rebuilt(value)
        elif isinstance(value, property):
            attrs[name] = property(rebuilt(value.fget), rebuilt(value.fset), rebuilt(value.fdel), value.__doc__)
    return types.new_class(cls.__name__, (cls,), {}, lambda ns: ns.update(attrs))  # type: ignore[return-value]


def run_atheris(load: Callable[[bool], Callable[[bytes], None]], module: str) -> None:
    """``load(True)`` imports the code under test inside :func:`instrument_only`; then fuzz.

    ``argv[0]`` becomes ``python -m MODULE``: libFuzzer's ``-fork``/``-jobs`` modes re-run it through
    the shell, and a module's ``.py`` path is not executable.

    What start-up made (modules, instrumented code, the target's fixtures: some 70 000 objects for
    the shell) lives as long as the process: after a collection it is frozen (``gc.freeze``), so the
    collector's full collections, triggered by the objects each input allocates, no longer traverse
    it (~70 ms each; 3-4 % of the shell target's time in a loop over its corpus).
    """
    import gc

    import atheris  # type: ignore[import-not-found,unused-ignore]

    one_input = load(True)
    gc.collect()
    gc.freeze()
    atheris.Setup([f"{sys.executable} -m {module}", *sys.argv[1:]], one_input)
    atheris.Fuzz()
