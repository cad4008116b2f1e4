"""``ghostshell log decode FILE --link SPEC`` when the link does not fit the file.

Found by a new user: a serial ``.jsonl`` given with a CAN ``--link`` printed python-can's "No read
support for unknown log format" ValueError; a CAN log given with a serial link was read as JSON Lines.
A ``--link`` (``?node=``) given with a run.mcap was ignored without a word. The exit-code table
(tests/cli/test_exit_codes.py) runs the first two as subprocesses; here the message's form.
"""

from __future__ import annotations

import contextlib
import io
from pathlib import Path

import pytest

from host.cli import main as cli_main


@pytest.mark.parametrize(("name", "link", "wants"), [
    ("host_frames.jsonl", "can:virtual?node=2", "records a CAN log (.log, .asc, .blf"),
    ("host_frames.log", "pty", "records a serial JSON Lines log (.jsonl)"),
])
def test_a_link_of_another_log_format_is_one_line_and_exit_2(tmp_path: Path, name: str, link: str, wants: str) -> None:
    f = tmp_path / name
    f.write_text("whatever\n")
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        assert cli_main(["log", "decode", str(f), "--link", link]) == 2
    assert err.getvalue().count("\n") == 1 and wants in err.getvalue() and str(f) in err.getvalue()
    assert "without --link the suffix picks the format" in err.getvalue()


def test_a_link_given_with_an_mcap_is_named_as_unused(tmp_path: Path) -> None:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        assert cli_main(["log", "decode", str(tmp_path / "run.mcap"), "--link", "can:virtual?node=2"]) == 2  # missing
    assert "note: --link is not used for an MCAP file" in err.getvalue()
