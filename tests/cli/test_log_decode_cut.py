"""``ghostshell log decode`` of a cut run.mcap: one line saying the file was cut and how many messages
were read, exit 1 (as a .jsonl with bad lines), at every place the file can be cut. A record cut inside
one of its fixed-size fields made the mcap package raise ``struct.error``, which ended the command with
a traceback."""

from __future__ import annotations

import io
import json
from pathlib import Path

from mcap.writer import Writer

from host.commands.log import decode_mcap_file

MESSAGES = 20


def _mcap(path: Path) -> bytes:
    """A small JSON-channel MCAP with many chunks (as a run's, flushed often)."""
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=160)
        w.start(profile="", library="test")
        schema = w.register_schema(name="state", encoding="jsonschema", data=b"{}")
        ch = w.register_channel(topic="/state", message_encoding="json", schema_id=schema)
        for i in range(MESSAGES):
            w.add_message(ch, log_time=i * 10_000_000, publish_time=i * 10_000_000, data=json.dumps({"i": i}).encode())
        w.finish()
    return path.read_bytes()


def test_every_cut_says_so_in_one_line_with_the_count(tmp_path: Path) -> None:
    whole = _mcap(tmp_path / "run.mcap")
    out, err = io.StringIO(), io.StringIO()
    assert decode_mcap_file(str(tmp_path / "run.mcap"), out, err) == 0
    assert len(out.getvalue().splitlines()) == MESSAGES
    cut = tmp_path / "cut.mcap"
    for n in range(8, len(whole)):
        cut.write_bytes(whole[:n])
        out, err = io.StringIO(), io.StringIO()
        assert decode_mcap_file(str(cut), out, err) == 1, n
        read = len(out.getvalue().splitlines())
        last = err.getvalue().splitlines()[-1]
        assert last.startswith(f"ghostshell log: {cut} ") and f"read {read} message(s)" in last, (n, last)
        assert "was cut" in last or "no summary" in last, (n, last)
