"""Example output in the guides that shows the host's schema hash shows the current one.

A new message changes the schema hash (:data:`protocol.codec.SCHEMA_HASH`); docs/wire-protocol.md is
regenerated, but the guides' example output (``schema: 0x...``, ``host schema 0x...``) is written by
hand, so this test names every stale one.
"""

from __future__ import annotations

import re
from pathlib import Path

from protocol.codec import WIRE_SCHEMA_16, WIRE_SCHEMA_32

DOCS = Path(__file__).resolve().parents[2] / "docs"
#: "schema: 0x1d7ad3a3 (u16 ..." and "host schema 0x1d7ad3a3 != board ...": the host's own hash
SHOWN = re.compile(r"(?:\bschema: |host schema )(0x[0-9a-fA-F]{8})")


def test_the_guides_show_the_current_schema_hashes() -> None:
    current = {WIRE_SCHEMA_16.hash, WIRE_SCHEMA_32.hash}
    seen, stale = 0, []
    for path in sorted(DOCS.rglob("*.md")):
        for n, line in enumerate(path.read_text().splitlines(), 1):
            for m in SHOWN.finditer(line):
                seen += 1
                if int(m.group(1), 16) not in current:
                    stale.append(f"{path.relative_to(DOCS)}:{n}: {m.group(1)}")
    assert seen >= 2, "no example output with a schema hash found: the pattern no longer matches the guides"
    assert not stale, "stale schema hashes (now " + ", ".join(f"0x{h:08x}" for h in sorted(current)) + "):\n" + "\n".join(stale)
