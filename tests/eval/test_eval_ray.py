"""``ghostshell eval --ray local``: the same sweep as Ray tasks on a local ``ray.init``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

pytest.importorskip("ray", reason="Ray is not installed (pip install 'ghostshell[ray]'); the --ray backend is optional")

from host.cli import main as cli  # noqa: E402
from host.tools.eval.dsbc import dsbc  # noqa: E402
from host.tools.eval.paper import hri_tasks  # noqa: E402
from support.fake_llm import FakeLLM, replay, stream_body  # noqa: E402


@pytest.mark.slow
def test_sweep_on_local_ray(fake_llm: FakeLLM, tmp_path: Path) -> None:
    replies = {1: "Sure! " + hri_tasks()[1].ground_truth, 3: '<head_act action="shake"/>'}
    by_instruction = {hri_tasks()[t].instruction: r for t, r in replies.items()}

    def respond(h, f):  # type: ignore[no-untyped-def]
        reply = by_instruction[f.requests[-1]["json"]["messages"][1]["content"]]
        replay(stream_body([reply]))(h, f)

    fake_llm.responder = respond
    out = tmp_path / "ray"
    assert cli(["eval", "--llm", "openai:m", "--base-url", fake_llm.base_url, "--api-key", "k", "--tasks", "1,3",
                "--trials", "1", "--workers", "2", "--ray", "local", "--out", str(out)]) == 0
    doc = json.loads((out / "eval.json").read_text())
    got = {r["task"]: (r["reply"], r["dsbc"], r["run"]["outcome"]) for r in doc["records"]}
    assert got == {t: (r, dsbc(hri_tasks()[t].ground_truth, r), "done") for t, r in replies.items()}
    assert (out / "runs" / "task-01-trial-0" / "timeline.json").exists()  # the board ran inside a Ray worker
