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
    assert "by its suffix" in err.getvalue()
    assert "without --link the suffix picks the format" in err.getvalue()


def test_a_link_given_with_an_mcap_is_named_as_unused(tmp_path: Path) -> None:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        assert cli_main(["log", "decode", str(tmp_path / "run.mcap"), "--link", "can:virtual?node=2"]) == 2  # missing
    assert "note: --link is not used for an MCAP file" in err.getvalue()


def test_a_file_the_link_fits_is_read_whatever_its_name_and_a_missing_one_is_named_as_missing(tmp_path: Path) -> None:
    """From a new user's pass: a candump saved as capture.txt (or with no suffix) could not be decoded at
    all (``--link can:…`` refused it by its suffix, and without it it was read as JSON Lines); a missing
    file or a folder given with a --link was blamed on its suffix."""
    from host.link.canlog import iter_can_log
    from protocol.can import encode_fixed
    from protocol.testing.samples import servo_frame_12

    lines = [f"({1000 + i * 0.001:.6f}) vcan0 {f.arbitration_id:03X}#{f.data.hex().upper()}"
             for i, f in enumerate(encode_fixed(servo_frame_12(), 7, 1))]
    for name in ("capture.txt", "capture"):
        f = tmp_path / name
        f.write_text("\n".join(lines) + "\n")
        assert len(list(iter_can_log(f))) == len(lines)
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            assert cli_main(["log", "decode", str(f), "--link", "can:virtual"]) == 0, err.getvalue()
        assert "SERVO_FRAME" in out.getvalue()
    for missing, says in ((tmp_path / "nope.jsonl", "No such file"), (tmp_path, "Is a directory")):
        err = io.StringIO()
        with contextlib.redirect_stderr(err):
            assert cli_main(["log", "decode", str(missing), "--link", "can:virtual"]) == 2
        assert says in err.getvalue() and "by its suffix" not in err.getvalue()
