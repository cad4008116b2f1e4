"""Checked-in generated files: write them, or check that they are current (one helper, one message format).

Every generator with a ``--check`` flag (``python -m protocol.cgen``, ``python -m firmware_sim.wire_reference``,
``python -m host.cli_reference``) ends in :func:`check_or_write`; ``protocol`` is the one package all three
may import. This module does file I/O, for those command-line entry points only: the codecs never call it.

Messages (stderr for problems, stdout for what was written), one line each::

    wrote PATH
    PATH is missing: run COMMAND
    PATH differs from the generated text: run COMMAND
    cannot write PATH: REASON

Exit status: 0 every file current (or written), 1 a file stale (``check``) or not writable.
"""

from __future__ import annotations

import sys
from collections.abc import Mapping
from pathlib import Path
from typing import IO

__all__ = ["check_or_write", "staleness"]


def staleness(path: Path, text: str) -> str | None:
    """Why ``path`` is not ``text`` (``"is missing"``, ``"differs from the generated text"``), None when it is.

    Compared as UTF-8 text (what the generators write)."""
    if not path.is_file():
        return "is missing"
    if path.read_text(encoding="utf-8") != text:
        return "differs from the generated text"
    return None


def check_or_write(files: Mapping[Path, str], *, check: bool, command: str,
                   out: IO[str] | None = None, err: IO[str] | None = None) -> int:
    """Write each ``path -> text`` of ``files`` (folders created), or with ``check`` only compare them.

    ``command`` is what regenerates them (named in the stale lines). Every stale file is reported, not
    only the first. Returns the exit status (0 or 1, see the module docstring); never raises for a file
    it cannot read or write (that is one line and status 1).
    """
    out = sys.stdout if out is None else out
    err = sys.stderr if err is None else err
    status = 0
    for path, text in files.items():
        try:
            if check:
                why = staleness(path, text)
                if why is not None:
                    print(f"{path} {why}: run {command}", file=err)
                    status = 1
                continue
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path}", file=out)
        except (OSError, UnicodeDecodeError) as e:
            reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
            print(f"cannot {'read' if check else 'write'} {path}: {reason}", file=err)
            status = 1
    return status
