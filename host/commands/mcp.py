"""``ghostshell mcp``: serve the shell over the Model Context Protocol (stdio or streamable HTTP)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the mcp options."""
    parser.add_argument("--http", type=int, default=None, metavar="PORT",
                        help="streamable HTTP on 127.0.0.1:PORT (path /mcp) instead of stdio")
    clock = parser.add_mutually_exclusive_group()
    clock.add_argument("--lockstep", dest="lockstep", action="store_true", help="virtual-time board")
    clock.add_argument("--realtime", dest="lockstep", action="store_false", help="wall-clock board (default)")
    parser.set_defaults(lockstep=False)
    parser.add_argument("--vocabulary", choices=("paper", "coco"), default="paper")
    parser.add_argument("--mode", choices=("async-first", "sync-first"), default="async-first")
    parser.add_argument("--scene", choices=("empty", "bottles"), default="empty")
    parser.add_argument("--link", default="pty", metavar="pty|PATH|URL")
    parser.add_argument("--out", type=Path, default=Path("runs/mcp"), help="session folder (frame logs, turns)")


def main(args: argparse.Namespace) -> int:
    """Serve until stdin closes (stdio) or the process is stopped (HTTP)."""
    try:
        from host.mcp_server.server import serve
    except ImportError as err:
        print(f"ghostshell mcp: the MCP SDK is missing ({err}); pip install 'mcp>=2'", file=sys.stderr)
        return 2
    from host.run.session import SessionOptions

    opts = SessionOptions(vocabulary=args.vocabulary, mode=args.mode, lockstep=args.lockstep, link=args.link,
                          out=args.out, label="mcp", scene=args.scene)
    serve(opts, args.http)
    return 0
