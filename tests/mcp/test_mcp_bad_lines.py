"""``ghostshell mcp`` over stdio answers a line that is not a JSON-RPC message with a JSON-RPC 2.0
error (id null: -32700 Parse error, -32600 Invalid Request) and goes on serving; the SDK alone
debug-logged and dropped it, so the client waited for an answer that never came."""

from __future__ import annotations

import json
import os
import select
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

pytestmark = pytest.mark.timeout(180)


def _reply(proc: subprocess.Popen[bytes], buf: bytearray, timeout: float = 120.0) -> dict[str, Any]:
    """The next JSON line the server writes (bounded wait on its stdout, no sleeps)."""
    assert proc.stdout is not None
    fd = proc.stdout.fileno()
    while b"\n" not in buf:
        ready, _, _ = select.select([fd], [], [], timeout)
        assert ready, "no reply from the server"
        chunk = os.read(fd, 65536)
        assert chunk, f"the server exited ({proc.poll()})"
        buf += chunk
    line, _, rest = bytes(buf).partition(b"\n")
    buf[:] = rest
    return dict(json.loads(line))


def test_bad_lines_get_a_jsonrpc_error_and_the_server_goes_on(tmp_path: Path) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "host", "mcp", "--lockstep", "--out", str(tmp_path / "mcp")],
                            stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdin is not None
    buf = bytearray()
    try:
        proc.stdin.write(b'{"jsonrpc": "2.0", "id": 1, "method": "initialize", oops\n')  # the input kept: not JSON
        proc.stdin.flush()
        assert _reply(proc, buf) == {"jsonrpc": "2.0", "id": None, "error": {"code": -32700, "message": "Parse error"}}
        proc.stdin.write(b'{"hello": "world"}\n')  # JSON, but no JSON-RPC message
        proc.stdin.flush()
        assert _reply(proc, buf)["error"]["code"] == -32600
        init = {"jsonrpc": "2.0", "id": 7, "method": "initialize",
                "params": {"protocolVersion": "2025-06-18", "capabilities": {},
                           "clientInfo": {"name": "test", "version": "1"}}}
        proc.stdin.write(json.dumps(init).encode() + b"\n")
        proc.stdin.flush()
        answer = _reply(proc, buf)
        assert answer["id"] == 7 and "result" in answer and "serverInfo" in answer["result"]
    finally:
        proc.stdin.close()
        try:
            proc.wait(60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        assert proc.stderr is not None
        proc.stderr.close()
        if proc.stdout is not None:
            proc.stdout.close()
