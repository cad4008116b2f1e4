"""A real LLM client end to end: ``--prompt`` + ``--llm openai:MODEL`` against a local SSE server.

The server (127.0.0.1, ephemeral port) answers the chat-completions request with
a streamed reply in the documented chunk format; the shell executes it on the
emulated board while it streams, and the system prompt it received describes
CoCo's functions.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import anyio

from host.run.runner import RunOptions, run_program
from support.fake_llm import FakeLLM, Handler, chunk, fake_llm, sse  # noqa: F401  (fixture)

REPLY = ['Sure! ', '<head_act action="n', 'od" duration="1"/>', '<wa', 've times="1"/>', 'Done.']


def test_prompt_streams_through_the_shell_onto_the_board(fake_llm: FakeLLM, tmp_path: Path) -> None:  # noqa: F811
    arrivals: list[float] = []

    def respond(h: Handler, fake: FakeLLM) -> None:
        h.start_sse()
        h.write_piece(sse(chunk("", role="assistant")))
        for piece in REPLY:
            h.write_piece(sse(chunk(piece)))
            arrivals.append(time.monotonic())
            time.sleep(0.05)  # the server's own pacing, like a real model; not test synchronisation
        h.write_piece(sse(chunk(None, finish="stop")))
        h.write_piece(b"data: [DONE]\n\n")
        h.end_chunked()

    fake_llm.responder = respond
    opts = RunOptions(prompt="Nod, then wave once, then say done.", llm="openai:test-model",
                      llm_base_url=fake_llm.base_url, llm_api_key="test-key", lockstep=True, out=tmp_path / "run")
    report = anyio.run(run_program, opts, backend="asyncio")

    (request,) = fake_llm.requests
    assert request["json"]["model"] == "test-model" and request["json"]["stream"] is True
    system, user = request["json"]["messages"]
    assert "<head_act" in system["content"] and "<wave" in system["content"]  # code as prompt (XML form)
    assert user["content"] == "Nod, then wave once, then say done."
    assert "".join(c for _, c in report.token_times) == "".join(REPLY)

    calls = {c.function: c for c in report.calls}
    assert set(calls) == {"head_act", "wave", "speak"}
    assert all(c.outcome == "done" for c in report.calls)
    assert calls["head_act"].args == {"action": "nod", "duration": 1.0}
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["outcome"] == "done" and summary["fell"] is False


def test_llm_errors_end_the_run_with_the_providers_message(fake_llm: FakeLLM, tmp_path: Path) -> None:  # noqa: F811
    body = json.dumps({"error": {"message": "Incorrect API key provided", "type": "invalid_request_error"}}).encode()
    fake_llm.responder = lambda h, f: h.send_json_error(401, body)
    opts = RunOptions(prompt="Nod.", llm="openai:test-model", llm_base_url=fake_llm.base_url,
                      llm_api_key="bad", lockstep=True, out=tmp_path / "run")
    report = anyio.run(run_program, opts, backend="asyncio")
    assert report.summary.outcome == "failed" and report.calls == []
    assert "Incorrect API key provided" in str(report.result.error) and "401" in str(report.result.error)
    assert any("the output stream failed" in o.message for o in report.result.observations)
    assert report.summary.duration_s < 1.0  # the lockstep board held still while the host waited
