"""Mounts: outside function providers as shell modules (today: MCP servers, ``--mount-mcp``).

A mount is a *source* of :class:`~host.shell.types.Module` s, like :func:`host.runtime.binding.robot_registry` is for
a robot's functions: the shell (``host/shell``) stays free of the MCP SDK and of subprocess I/O, and
another kind of mount (another robot's shell, item 5) goes beside it.

* :mod:`host.mounts.spec`: ``parse_mount_arg(text) -> MountSpec`` (``MountSpecError``), ``check_specs``
  (``McpMountError``: names refused before anything starts, without the SDK);
* :mod:`host.mounts.schema`: JSON Schema -> typed parameters (pure; the mapping table);
* :mod:`host.mounts.stdio`: the bounded stdio transport for the SDK's ``Client``;
* :mod:`host.mounts.mcp_mount`: ``mounted(specs, registry=..., options=...)``, ``McpMount``,
  ``McpCallError``, ``MountOptions`` (and ``McpMountError``, ``check_specs`` again).

Public names are imported lazily (the SDK loads only when a server is mounted).
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "MountSpec": "host.mounts.spec",
    "MountSpecError": "host.mounts.spec",
    "parse_mount_arg": "host.mounts.spec",
    "mounted": "host.mounts.mcp_mount",
    "check_specs": "host.mounts.spec",
    "McpMount": "host.mounts.mcp_mount",
    "McpMountError": "host.mounts.spec",
    "McpCallError": "host.mounts.mcp_mount",
    "MountOptions": "host.mounts.mcp_mount",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'host.mounts' has no attribute {name!r}")
    return getattr(importlib.import_module(mod), name)
