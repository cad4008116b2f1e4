"""A damaged or garbage log gives one line naming the file and exit status 2, in every command that reads one.

Found by a reviewer: ``render DIR`` with a truncated or garbage ``board_frames.jsonl`` ended in a
``protocol.framelog.FrameLogError`` traceback (exit 1); ``replay g.blf`` of a garbage .blf printed 48
lines ending ``struct.error: unpack requires a buffer of 72 bytes``; ``replay g.trc`` printed python-can's
TRCReader warnings as extra lines; ``replay g.mf4`` said "The asammdf package was not found" with exit 1.
python-can's readers now fail as :class:`host.link.canlog.CanLogError` (naming the file) with their
logging kept off stderr, and ``render`` maps a damaged frame log to its bad-input error.

In-process through :func:`host.cli.main`; nothing starts (every row is refused while reading the log).
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest

from support.cli_refusal import refused


pytestmark = pytest.mark.timeout(120)

#: name -> bytes of a damaged log
DAMAGED: dict[str, bytes] = {
    "truncated.blf": b"LOGG" + b"\x00" * 40,  # the header cut short: struct.error in python-can's reader
    "garbage.blf": bytes(range(256)) * 2,  # not a BLF at all: BLFParseError
    "binary.trc": b"\xe2\x28\xa1" * 100,  # not text: UnicodeDecodeError
    "text.trc": b"garbage line\nmore garbage\n;$FILEVERSION=9.9\n",  # text python-can's TRCReader warns about
    "garbage.mf4": b"\x00\x01garbage" * 50,  # asammdf missing, or (with it) not an MF4
    "garbage.asc": b"\xff\xfe\x00garbage\n" * 20,
}


@pytest.fixture(autouse=True)
def _here(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.chdir(tmp_path)


def _no_can_warnings(caplog: pytest.LogCaptureFixture) -> None:
    leaked = [r for r in caplog.records if r.name.startswith("can")]
    assert not leaked, [r.getMessage() for r in leaked]  # would reach stderr as extra lines


@pytest.mark.parametrize("name", sorted(DAMAGED))
def test_replay_refuses_a_damaged_can_log(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    path = tmp_path / name
    path.write_bytes(DAMAGED[name])
    line = refused(["replay", str(path), "--out", str(tmp_path / "out")], capsys)
    assert name in line, line
    _no_can_warnings(caplog)


@pytest.mark.parametrize("name", sorted(DAMAGED))
def test_log_decode_refuses_a_damaged_can_log(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                              caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.DEBUG)
    path = tmp_path / name
    path.write_bytes(DAMAGED[name])
    line = refused(["log", "decode", str(path)], capsys)
    assert str(path) in line, line
    assert "CanLogError" not in line, line  # the reader's own line, not wrapped twice
    _no_can_warnings(caplog)


def test_a_damaged_blf_names_the_reader_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "truncated.blf"
    path.write_bytes(DAMAGED["truncated.blf"])
    line = refused(["replay", str(path), "--out", str(tmp_path / "out")], capsys)
    assert f"cannot read {path} as a .blf log" in line and "unpack requires" in line, line


def test_mf4_without_asammdf_is_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("can")
    try:
        import asammdf  # noqa: F401
        pytest.skip("asammdf is installed: the optional-package path is not taken")
    except ImportError:
        pass
    path = tmp_path / "garbage.mf4"
    path.write_bytes(DAMAGED["garbage.mf4"])
    line = refused(["replay", str(path), "--out", str(tmp_path / "out")], capsys)
    assert "needs an optional package" in line and "asammdf" in line, line


@pytest.mark.parametrize("content", [b'{"t": 1, "dir": "tx", "ty', b"garbage\n", b"\xff\xfe\x00\x01\n",
                                     b'{"t": 1, "dir": "tx", "type": "TELEMETRY", "fields": {}}\n'],
                         ids=["truncated", "garbage", "binary", "fields-missing"])
def test_render_refuses_a_damaged_frame_log(content: bytes, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    (run / "board_frames.jsonl").write_bytes(content)
    (run / "timeline.json").write_text('{"calls": []}', encoding="utf-8")
    line = refused(["render", str(run), "--quiet"], capsys)
    assert str(run / "board_frames.jsonl") in line, line
    assert not (run / "run.mp4").exists()


@pytest.mark.parametrize("name", ["truncated.blf", "binary.trc"])
def test_render_refuses_a_damaged_can_capture(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = tmp_path / "run"
    run.mkdir()
    suffix = Path(name).suffix
    (run / f"board_frames{suffix}").write_bytes(DAMAGED[name])
    line = refused(["render", str(run), "--quiet"], capsys)
    assert str(run / f"board_frames{suffix}") in line, line


@pytest.mark.parametrize("content", ['{"calls": [{"start": 1', '{"calls": [{"start": 0, "end": 1, "channel": "head"}]}', "[]"],
                         ids=["truncated", "no-function", "not-an-object"])
def test_render_refuses_a_damaged_timeline(content: str, tmp_path: Path) -> None:
    """The timeline is read after the frame log: a damaged one is render's bad input too (was a traceback)."""
    from host.run.video import VideoInputError, _calls

    (tmp_path / "timeline.json").write_text(content, encoding="utf-8")
    with pytest.raises(VideoInputError, match="timeline.json is not a readable timeline"):
        _calls(tmp_path)
