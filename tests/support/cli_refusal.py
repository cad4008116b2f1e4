"""Run a ``ghostshell`` command in-process and check it was refused as bad input (tests/cli)."""

from __future__ import annotations

from collections.abc import Sequence

import pytest

import host.cli


def refused(argv: Sequence[str], capsys: pytest.CaptureFixture[str], *, quiet_stdout: bool = False) -> str:
    """``host.cli.main(argv)`` (an argparse usage error included): its one stderr line, asserted to be the
    only one, with exit status 2 and no traceback; ``quiet_stdout``: nothing on stdout either."""
    status: int | str | None
    try:
        status = host.cli.main(list(argv))
    except SystemExit as e:  # argparse's usage error (a type= check)
        status = e.code
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert status == 2, f"status {status}\n{err}\n{out}"
    assert "Traceback" not in err + out, err
    assert len(lines) == 1 and lines[0].startswith(f"ghostshell {argv[0]}"), err
    if quiet_stdout:
        assert out == "", out  # no banner, no "removed the earlier run's artefacts"
    return lines[0]
