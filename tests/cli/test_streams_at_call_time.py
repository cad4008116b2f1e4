"""Commands print to the streams in effect when they run, not to the ones of the first import.

The reported failure: ``ghostshell log decode run.mcap`` printed to a ``sys.stdout`` captured as a
default argument when :mod:`host.commands.log` was first imported (by an earlier test), so a later
redirect of ``sys.stdout`` saw nothing. Kept as a test for both decoders, and for the whole kind:
no function in host/, firmware_sim/ or protocol/ takes ``sys.stdout``/``sys.stderr`` as a default.
"""

from __future__ import annotations

import ast
import contextlib
import io
from pathlib import Path

import host.commands.log as log_cmd  # imported first, as in a long test session
from protocol.framelog import record, to_line
from protocol.framing import encode_frame
from protocol.messages import Estop

ROOT = Path(__file__).resolve().parents[2]


def test_decode_prints_to_the_stdout_of_the_call(tmp_path: Path) -> None:
    f = tmp_path / "host.jsonl"
    f.write_text(to_line(record("tx", 0.5, encode_frame(Estop(), 7))) + "\n")
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        assert log_cmd.decode_file(str(f)) == 0
        assert log_cmd.decode_mcap_file(str(tmp_path / "missing.mcap")) == 2
    assert "ESTOP" in out.getvalue()
    assert "ghostshell log:" in err.getvalue()


def test_no_default_argument_is_a_process_stream() -> None:
    found = []
    for pkg in ("host", "firmware_sim", "protocol", "robots"):
        for path in (ROOT / pkg).rglob("*.py"):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    for d in node.args.defaults + [d for d in node.args.kw_defaults if d is not None]:
                        if ast.unparse(d) in ("sys.stdout", "sys.stderr"):
                            found.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name}")
    assert not found, found
