"""``ghostshell eval`` refuses bad arguments up front (exit 2, one message) and never mixes two sweeps in one --out."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from host.cli import main as cli
from host.tools.eval.paper import hri_tasks
from support.fake_llm import FakeLLM, Handler, replay, stream_body

BY_INSTRUCTION = {t.instruction: t for t in hri_tasks().values()}


def serve_replies(fake: FakeLLM) -> None:
    """Answer each task with its ground truth."""

    def respond(h: Handler, f: FakeLLM) -> None:
        task = BY_INSTRUCTION[f.requests[-1]["json"]["messages"][1]["content"]]
        replay(stream_body([task.ground_truth]))(h, f)

    fake.responder = respond


def test_reversed_task_range_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["eval", "--llm", "openai:m", "--api-key", "k", "--tasks", "5-2", "--out", str(tmp_path / "e")]) == 2
    assert "5-2" in capsys.readouterr().err and not (tmp_path / "e").exists()


def test_an_empty_task_list_is_refused_not_taken_as_all(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``--tasks ''`` (a shell variable left empty) ran all 30 tasks; ``all`` says so."""
    assert cli(["eval", "--llm", "ground-truth", "--tasks", "", "--out", str(tmp_path / "e")]) == 2
    assert "no task ids" in capsys.readouterr().err and not (tmp_path / "e").exists()


@pytest.mark.parametrize("llm", ["bogus", "openai:", "scripted"])
def test_bad_llm_spec_fails_once_up_front(llm: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["eval", "--llm", llm, "--tasks", "1-3", "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err
    assert err.count("ghostshell eval:") == 1 and not (tmp_path / "e").exists()


def test_missing_api_key_fails_once_up_front(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    for var in ("GHOSTSHELL_LLM_API_KEY", "OPENAI_API_KEY", "GHOSTSHELL_LLM_BASE_URL", "OPENAI_BASE_URL"):
        monkeypatch.delenv(var, raising=False)
    assert cli(["eval", "--llm", "openai:m", "--base-url", "https://api.example.invalid/v1", "--tasks", "1-3",
                "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err
    assert err.count("no API key") == 1 and not (tmp_path / "e").exists()


def test_other_tasks_or_fewer_trials_into_the_same_out_are_refused(
        fake_llm: FakeLLM, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    serve_replies(fake_llm)
    out = tmp_path / "ev"
    base = ["eval", "--llm", "openai:m", "--base-url", fake_llm.base_url, "--api-key", "k", "--no-run",
            "--out", str(out)]
    assert cli(base + ["--tasks", "1-2", "--trials", "2"]) == 0
    md = (out / "eval.md").read_text()
    capsys.readouterr()
    assert cli(base + ["--tasks", "1", "--trials", "2"]) == 2
    assert "tasks" in capsys.readouterr().err
    assert cli(base + ["--tasks", "1-2", "--trials", "1"]) == 2
    assert "trials" in capsys.readouterr().err
    assert (out / "eval.md").read_text() == md and len(fake_llm.requests) == 4
    # more trials extends the sweep; the counter counts only this sweep's jobs
    assert cli(base + ["--tasks", "1-2", "--trials", "3"]) == 0
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("[")]
    assert [x.split("]")[0] for x in lines] == ["[5/6", "[6/6"]
    assert json.loads((out / "config.json").read_text())["trials"] == 3


def test_no_plots_with_no_run_is_refused_not_ignored(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli(["eval", "--llm", "ground-truth", "--tasks", "1", "--no-run", "--no-plots",
                "--out", str(tmp_path / "e")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--no-plots with --no-run" in err[0], err
    assert not (tmp_path / "e").exists()
