"""The GhostShell shell: streaming function-token parser, mapper, scheduler, prompt.

Public names are imported lazily so that importing one submodule (e.g. the
parser) does not pull in the rest.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Shell": "host.shell.shell",
    "Registry": "host.shell.registry",
    "RegistryError": "host.shell.registry",
    "Module": "host.shell.types",
    "Range": "host.shell.types",
    "shell_function": "host.shell.types",
    "MAIN_CHANNEL": "host.shell.types",
    "CallContext": "host.shell.context",
    "RunResult": "host.shell.timeline",
    "CallRecord": "host.shell.timeline",
    "Observation": "host.shell.timeline",
    "Timeline": "host.shell.timeline",
    "SkillStore": "host.shell.skills",
    "render_prompt": "host.shell.prompt",
    "MappingError": "host.shell.mapper",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'host.shell' has no attribute {name!r}")
    return getattr(importlib.import_module(mod), name)
