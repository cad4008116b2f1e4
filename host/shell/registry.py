"""The function registry: modules mounted and unmounted at runtime.

Every mounted function (and each of its aliases) is resolvable by element name, exactly
as mounted: a qualified name such as ``weather.get_forecast`` (an MCP tool, ``host.mounts``)
is one name, and its bare ``get_forecast`` does not resolve (it is only suggested).
Mount order is kept, so the prompt lists modules in the order they were mounted.
``version`` increases on every change so callers can re-render the prompt.
"""

from __future__ import annotations

import difflib
from collections.abc import Callable, Iterable

from host.shell.types import BUILTINS, MAIN_CHANNEL, FunctionSpec, Module


class RegistryError(ValueError):
    """A mount or unmount that would leave the registry inconsistent."""


class UnknownFunction(LookupError):
    """No mounted function has this element name."""

    def __init__(self, name: str, suggestions: list[str]) -> None:
        self.name = name
        self.suggestions = suggestions
        hint = f"; did you mean {', '.join(suggestions)}?" if suggestions else ""
        super().__init__(f"unknown function <{name}>{hint}")


class Registry:
    """Mounted modules and the name -> function table they define."""

    def __init__(self, modules: Iterable[Module] = ()) -> None:
        self._modules: dict[str, Module] = {}
        self._names: dict[str, FunctionSpec] = {}
        self._listeners: list[Callable[[Registry], None]] = []
        self.version = 0
        for m in modules:
            self.mount(m)

    # -- mounting ---------------------------------------------------------
    def mount(self, module: Module) -> None:
        """Mount ``module``; its functions and aliases become callable and appear in the prompt."""
        if module.name in self._modules:
            raise RegistryError(f"module {module.name!r} is already mounted")
        if module.channel == MAIN_CHANNEL:
            raise RegistryError(f"module {module.name!r} may not use the main channel")
        new: dict[str, FunctionSpec] = {}
        for spec in module.functions:
            for n in (spec.name, *spec.aliases):
                if n in BUILTINS:
                    raise RegistryError(f"{module.name}.{spec.name}: {n!r} is a built-in element name")
                if n in self._names or n in new:
                    owner = (self._names.get(n) or new[n]).module
                    raise RegistryError(f"{module.name}: function name {n!r} already provided by module {owner!r}")
                new[n] = spec
        if sum(s.speech for s in module.functions) + (self.speech is not None) > 1:
            raise RegistryError(f"module {module.name!r}: only one speech function may be mounted")
        self._modules[module.name] = module
        self._names.update(new)
        self._changed()

    def unmount(self, name: str) -> Module:
        """Unmount the module called ``name`` and return it."""
        module = self._modules.pop(name, None)
        if module is None:
            raise RegistryError(f"module {name!r} is not mounted; mounted: {sorted(self._modules)}")
        self._names = {n: s for n, s in self._names.items() if s.module != name}
        self._changed()
        return module

    def alias(self, alias: str, target: str) -> None:
        """Make ``alias`` a second element name for the mounted function ``target``."""
        spec = self.resolve(target)
        if alias in BUILTINS or alias in self._names:
            raise RegistryError(f"name {alias!r} is already taken")
        self._names[alias] = spec
        self._changed()

    def on_change(self, listener: Callable[[Registry], None]) -> None:
        """Call ``listener(registry)`` after every mount, unmount or alias."""
        self._listeners.append(listener)

    def _changed(self) -> None:
        self.version += 1
        for cb in list(self._listeners):
            cb(self)

    # -- lookup -------------------------------------------------------------
    def resolve(self, name: str) -> FunctionSpec:
        """The function mounted as ``name``; :class:`UnknownFunction` lists close matches."""
        try:
            return self._names[name]
        except KeyError:
            # a qualified name "module.fn" (e.g. an MCP tool) called by its bare "fn" is suggested first
            qualified = [n for n in self._names if n.rpartition(".")[2] == name and n != name][:3]
            close = difflib.get_close_matches(name, list(self._names) + sorted(BUILTINS), n=3, cutoff=0.6)
            raise UnknownFunction(name, (qualified + [c for c in close if c not in qualified])[:3]) from None

    def __contains__(self, name: object) -> bool:
        return name in self._names

    def modules(self) -> list[Module]:
        """Mounted modules in mount order."""
        return list(self._modules.values())

    def functions(self) -> list[FunctionSpec]:
        """Mounted functions (each once, aliases not repeated) in mount order."""
        return [s for m in self._modules.values() for s in m.functions]

    def aliases_of(self, spec: FunctionSpec) -> list[str]:
        """Every name other than ``spec.name`` that resolves to ``spec``."""
        return [n for n, s in self._names.items() if s is spec and n != spec.name]

    def channels(self) -> list[str]:
        """The main channel followed by one channel per module (deduplicated)."""
        out = [MAIN_CHANNEL]
        for m in self._modules.values():
            if m.channel not in out:
                out.append(m.channel)
        return out

    @property
    def speech(self) -> FunctionSpec | None:
        """The mounted speech function that plain text maps to, if any."""
        for s in self.functions():
            if s.speech:
                return s
        return None
