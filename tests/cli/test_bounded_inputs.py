"""A user-given file or standard input is read to a cap, never whole: more is refused with one line, exit 2.

Found by a reviewer: ``run --xml-file /dev/zero`` read the whole "file" (24 GB, then the OOM killer:
exit 137; with ``ulimit -v`` a MemoryError traceback), and ``yes '<head_act .../>' | ghostshell run
--xml-file -`` did the same. Every input read whole now goes through :mod:`host.bounded_read` (caps:
4 MiB programs and turns, 1 MiB policies, 2 MiB event files, 32 MiB skill libraries): ``/dev/zero``, an
endless pipe and a file over the cap are refused after cap + 1 bytes, before ``--out`` is touched; a
FIFO with no writer reads as empty (refused as empty) instead of hanging. ``log decode`` / ``replay``
refuse a device or FIFO as a log, and ``log decode`` a line no frame record can be.

The rows run in-process through :func:`host.cli.main`; the endless pipe is a real pipe on stdin.
"""

from __future__ import annotations

import io
import os
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from support.cli_refusal import refused

import host.cli

pytestmark = pytest.mark.timeout(120)

MAX_TEXT = 4 * 1024 * 1024  # host.bounded_read.MAX_TEXT (imported where used, so the rows run on any version)

NOD = '<head_act action="nod"/>'
EARLIER = {"summary.json": b'{"outcome": "done"}\n', "board_frames.jsonl": b'{"t": 2}\n', "notes.txt": b"mine\n"}


@pytest.fixture(autouse=True)
def _here(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for name in ("GHOSTSHELL_LLM_MODEL", "GHOSTSHELL_LLM_API_KEY", "OPENAI_API_KEY", "ANTHROPIC_API_KEY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)


@pytest.fixture
def fifo(tmp_path: Path) -> Path:
    path = tmp_path / "fifo"
    os.mkfifo(path)
    return path


@pytest.fixture
def big(tmp_path: Path) -> Path:
    """A (sparse) regular file one byte over the text cap."""
    path = tmp_path / "big.xml"
    with open(path, "wb") as f:
        f.truncate(MAX_TEXT + 1)
    return path


@pytest.fixture
def endless_stdin(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Standard input is a pipe a thread fills with nods until the reader closes it (``yes NOD |``)."""
    r, w = os.pipe()
    line = (NOD + "\n").encode() * 1000

    def fill() -> None:
        try:
            with open(w, "wb", buffering=0) as f:
                while True:
                    f.write(line)
        except OSError:  # the read end closed: the command stopped reading
            pass

    t = threading.Thread(target=fill, daemon=True)
    t.start()
    stdin = io.TextIOWrapper(open(r, "rb"), encoding="utf-8")
    monkeypatch.setattr(sys, "stdin", stdin)
    yield
    stdin.close()
    t.join(timeout=30)
    assert not t.is_alive()


# (argv, what the one line says); {X} is the input under test
ROWS: list[tuple[tuple[str, ...], str]] = [
    (("run", "--xml-file", "{X}"), "--xml-file {X}: it holds more than 4 MiB"),
    (("chat", "--turns", "{X}"), "--turns {X}: it holds more than 4 MiB"),
    (("chat", "--replies", "{X}"), "--replies {X}: it holds more than 4 MiB"),
    (("run", "--task", "1", "--policy", "{X}"), "policy {X}: it holds more than 1 MiB"),
    (("run", "--task", "1", "--events", "{X}"), "--events {X}: it holds more than 2 MiB"),
    (("run", "--task", "1", "--skills", "{X}"), "skill library {X}: it holds more than 32 MiB"),
]


@pytest.mark.parametrize(("argv", "says"), ROWS, ids=[" ".join(a) for a, _ in ROWS])
def test_dev_zero_is_refused_before_the_out_folder_is_touched(argv: tuple[str, ...], says: str, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "earlier"
    out.mkdir()
    for name, data in EARLIER.items():
        (out / name).write_bytes(data)
    args = [a.replace("{X}", "/dev/zero") for a in argv]
    line = refused([*args, "--lockstep", "--no-live", "--out", str(out)], capsys)
    assert says.replace("{X}", "/dev/zero") in line, line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == EARLIER


def test_eval_replies_from_dev_zero_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    line = refused(["eval", "--llm", "scripted", "--replies", "/dev/zero", "--tasks", "1", "--trials", "1"], capsys)
    assert "--replies /dev/zero: it holds more than 4 MiB" in line


def test_a_program_over_the_cap_is_refused(big: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    line = refused(["run", "--xml-file", str(big), "--lockstep", "--no-live", "--no-plots", "--out", str(out)], capsys)
    assert f"--xml-file {big}: it holds more than 4 MiB" in line, line
    assert not out.exists()


def test_an_endless_pipe_on_stdin_is_refused(endless_stdin: None, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    line = refused(["run", "--xml-file", "-", "--lockstep", "--no-live", "--no-plots", "--out", str(out)], capsys)
    assert "--xml-file - (standard input): it holds more than 4 MiB" in line, line
    assert not out.exists()


def test_a_fifo_without_a_writer_does_not_hang(fifo: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "out"
    line = refused(["run", "--xml-file", str(fifo), "--lockstep", "--no-live", "--no-plots", "--out", str(out)], capsys)
    assert f"--xml-file {fifo} is empty" in line, line
    assert not out.exists()


@pytest.mark.parametrize("command", ["log", "replay"])
@pytest.mark.parametrize("special", ["/dev/zero", "{FIFO}"])
def test_a_device_or_fifo_is_no_log(command: str, special: str, fifo: Path, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    path = special.replace("{FIFO}", str(fifo))
    argv = ["log", "decode", path] if command == "log" else ["replay", path, "--out", str(tmp_path / "o")]
    line = refused(argv, capsys)
    assert f"{path} is a {'device' if path == '/dev/zero' else 'FIFO'}, not a log file" in line, line


def test_log_decode_refuses_a_line_no_record_can_be(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "long.jsonl"
    path.write_bytes(b"a" * (2 * 1024 * 1024))
    line = refused(["log", "decode", str(path)], capsys)
    assert f"{path}:1 is longer than" in line, line


def test_read_capped(tmp_path: Path, fifo: Path) -> None:
    from host.bounded_read import MAX_TEXT as cap
    from host.bounded_read import InputTooLarge, read_capped, special_file_problem

    assert cap == MAX_TEXT
    exact = tmp_path / "exact"
    exact.write_bytes(b"x" * 100)
    assert read_capped(exact, 100) == b"x" * 100
    with pytest.raises(InputTooLarge, match="more than 99 bytes"):
        read_capped(exact, 99)
    with pytest.raises(InputTooLarge):
        read_capped("/dev/zero", 1000)
    assert read_capped(fifo, 1000) == b""  # no writer: empty, at once
    with pytest.raises(IsADirectoryError):
        read_capped(tmp_path, 10)
    assert special_file_problem(exact) is None and special_file_problem(tmp_path / "none") is None
    assert special_file_problem("/dev/null") is not None


def test_chat_ends_input_at_a_line_over_the_cap(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """``chat < /dev/zero``: one line, exit 2, the transcript kept (was: one endless line read into memory)."""
    zero = open("/dev/zero", encoding="utf-8")  # noqa: SIM115 - closed below
    monkeypatch.setattr(sys, "stdin", zero)
    try:
        status = host.cli.main(["chat", "--llm", "scripted", "--lockstep", "--no-live", "--out", str(tmp_path / "c")])
    finally:
        zero.close()
    out, err = capsys.readouterr()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert status == 2, err
    assert len(lines) == 1 and "a line of standard input is longer than" in lines[0], err
    assert "Traceback" not in err + out


def test_dsbc_stdin_and_file_are_capped(monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    assert "GT /dev/zero: it holds more than 4 MiB" in refused(["dsbc", "@/dev/zero", NOD], capsys)
    zero = open("/dev/zero", encoding="utf-8")  # noqa: SIM115 - closed below
    monkeypatch.setattr(sys, "stdin", zero)
    try:
        assert "GT - (standard input): it holds more than 4 MiB" in refused(["dsbc", "-", NOD], capsys)
    finally:
        zero.close()
