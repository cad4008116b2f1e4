"""The shell as an MCP server (``ghostshell mcp``); see :mod:`host.mcp_server.server`."""

from host.mcp_server.server import build_server

__all__ = ["build_server"]
