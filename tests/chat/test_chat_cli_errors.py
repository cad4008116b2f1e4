"""``ghostshell chat`` and ``run``: bad input files and arguments give one clear message and exit 2 (no traceback);
a chat whose every LLM request failed exits nonzero; end of piped input lets the running turn finish."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from host.cli import main as cli
from support.fake_llm import FakeLLM, fake_llm  # noqa: F401  (fixture)

BAD = b"\xff\xfe<\x00h\x00"  # a UTF-16 byte order mark: not UTF-8


@pytest.mark.parametrize("argv", [
    ["run", "--xml-file", "{bad}", "--lockstep", "--no-live"],
    ["run", "--xml", "<nod/>", "--policy", "{bad}", "--lockstep", "--no-live"],
    ["run", "--xml", "<nod/>", "--skills", "{bad}", "--lockstep", "--no-live"],
    ["chat", "--replies", "{bad}", "--lockstep", "--no-live"],
    ["chat", "--llm", "openai:m", "--api-key", "k", "--turns", "{bad}", "--lockstep", "--no-live"],
    ["skills", "--skills", "{bad}", "list"],
    ["dsbc", "@{bad}", "<nod/>"],
])
def test_a_non_utf8_input_file_is_one_clear_error(argv: list[str], tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.xml"
    bad.write_bytes(BAD)
    rc = cli([a.replace("{bad}", str(bad)) for a in argv])
    err = capsys.readouterr().err
    assert rc in (1, 2) and str(bad) in err, err
    assert "Traceback" not in err and err.count("\n") <= 2


def test_run_on_a_non_utf8_file_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.xml"
    bad.write_bytes(BAD)
    assert cli(["run", "--xml-file", str(bad), "--lockstep", "--no-live", "--out", str(tmp_path / "o")]) == 2
    assert "not UTF-8" in capsys.readouterr().err


@pytest.mark.parametrize("replies,turns,needle", [
    ("\n---\n\n", None, "holds no reply"),
    ("<nod/>\n", "one\n---\ntwo\n", "2 turns"),
])
def test_replies_that_cannot_cover_the_turns_are_refused_up_front(
        replies: str, turns: str | None, needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "r.txt").write_text(replies)
    argv = ["chat", "--replies", str(tmp_path / "r.txt"), "--lockstep", "--no-live", "--out", str(tmp_path / "c")]
    if turns is not None:
        (tmp_path / "t.txt").write_text(turns)
        argv += ["--turns", str(tmp_path / "t.txt")]
    assert cli(argv) == 2
    assert needle in capsys.readouterr().err and not (tmp_path / "c").exists()


def test_bad_llm_spec_is_refused_up_front(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "t.txt").write_text("hi\n")
    assert cli(["chat", "--llm", "bogus", "--turns", str(tmp_path / "t.txt"), "--no-live",
                "--out", str(tmp_path / "c")]) == 2
    assert "unknown LLM spec" in capsys.readouterr().err and not (tmp_path / "c").exists()


def test_chat_whose_every_llm_request_failed_exits_nonzero(fake_llm: FakeLLM, tmp_path: Path,  # noqa: F811
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    fake_llm.responder = lambda h, f: h.send_json_error(400, b'{"error": {"message": "no such model"}}')
    (tmp_path / "t.txt").write_text("Nod.\n---\nWave.\n")
    rc = cli(["chat", "--llm", "openai:m", "--base-url", fake_llm.base_url, "--api-key", "k",
              "--turns", str(tmp_path / "t.txt"), "--lockstep", "--no-live", "--out", str(tmp_path / "c")])
    assert rc == 1 and "every LLM request failed" in capsys.readouterr().err
    doc = json.loads((tmp_path / "c" / "transcript.json").read_text())
    assert all("no such model" in s["stream_error"] for t in doc["turns"] for s in t["steps"])


def test_end_of_piped_input_lets_the_last_turn_finish(tmp_path: Path) -> None:
    out = tmp_path / "c"
    proc = subprocess.run([sys.executable, "-m", "host", "chat", "--lockstep", "--no-live", "--out", str(out)],
                          input='<head_act action="nod"/>\n', capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads((out / "transcript.json").read_text())
    assert len(doc["turns"]) == 1 and not doc["turns"][0]["interrupted"]
    assert doc["turns"][0]["steps"][0]["outcome"] == "done"


@pytest.mark.parametrize("argv, needle", [  # found by a fresh-user review
    (["run", "--task", "1", "--lockstep", "--fault-seed", "-1"], "must be an integer >= 0"),
    (["run", "--task", "1", "--lockstep", "--fault-seed", "3"], "--fault-seed has no effect without --faults"),
    (["run", "--task", "1", "--link", "/dev/pts/9999", "--faults", "drop=0.1"], "is a board you started"),
    (["demo", "--faults", "dorp=0.1"], "did you mean drop"),
    (["fuzz", "serial-decoder", "--corpus", "/proc/nope/corpus", "--seconds", "1"], "--corpus: /proc/nope/corpus cannot be created"),
    (["fuzz", "serial-decoder", "--max-len", "0"], "--max-len must be at least 1"),
])
def test_bad_fault_and_fuzz_arguments_are_one_line_before_anything_runs(
        argv: list[str], needle: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    try:  # argparse's own checks exit 2 (SystemExit); the command's return 2
        rc = cli(argv + (["--out", str(tmp_path / "o")] if argv[0] != "fuzz" else []))
    except SystemExit as e:
        rc = e.code
    assert rc == 2
    out, err = capsys.readouterr()
    assert needle in err and "Traceback" not in err
    assert out == ""  # nothing before the error: no task banner, no board
    assert not (tmp_path / "o").exists()
