"""DONE criterion of multi-turn chat: a batch chat against a local OpenAI-compatible server.

The server (real HTTP, the documented SSE chunk format) answers each request
with the next canned reply and records what it received. The requests must
show the history the issue asks for: the previous turn's observations as a
user-side message, and the previous reply as it was executed (an interrupted
reply trimmed at the cut); a reply that looks (``<capture/>``) gets its
observations back, with the photo as an image part, within the same turn.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

from host.cli import main as cli_main
from support.fake_llm import FakeLLM, Handler, fake_llm, replay, stream_body  # noqa: F401  (fixture)
import pytest

REPLIES = [
    ['<head_act action="nod" ', 'duration="1"/>Hello', ' there.'],
    ['<move_strides direction="forward" times="6"/>', '<wait><wave/></wait>', 'Never spoken.'],
    ['Let me look.<capture/>'],
    ['<observe/>'],  # turn 3, step 2: looks again
    ['I saw it.'],  # turn 3, step 3
]
TURNS = "Nod and greet me.\n--- interrupt-after 0.6\nWalk forward a lot.\n---\nWhat do you see?\n"


def _text(message: dict[str, Any]) -> str:
    c = message["content"]
    return c if isinstance(c, str) else "\n".join(p.get("text", "") for p in c if p.get("type") == "text")


def test_batch_chat_history_reaches_the_llm(fake_llm: FakeLLM, tmp_path: Path) -> None:  # noqa: F811
    def respond(h: Handler, fake: FakeLLM) -> None:
        replay(stream_body(REPLIES[len(fake.requests) - 1]))(h, fake)

    fake_llm.responder = respond
    (tmp_path / "turns.txt").write_text(TURNS, encoding="utf-8")
    out = tmp_path / "chat"
    rc = cli_main(["chat", "--llm", "openai:test-model", "--base-url", fake_llm.base_url, "--api-key", "k",
                   "--turns", str(tmp_path / "turns.txt"), "--lockstep", "--no-live", "--vision",
                   "--max-steps", "3", "--out", str(out)])
    assert rc == 0
    reqs = [r["json"]["messages"] for r in fake_llm.requests]
    assert len(reqs) == 5

    # every request starts with the code-as-prompt, which documents <observe/>
    assert all(m[0]["role"] == "system" and "observe" in m[0]["content"] and "head_act" in m[0]["content"]
               for m in reqs)
    # turn 2's request: turn 1's executed reply, then its observations with the user's next message
    second = reqs[1]
    assert [m["role"] for m in second] == ["system", "user", "assistant", "user"]
    assert second[2]["content"] == '<head_act action="nod" duration="1"/>Hello there.'
    obs1 = _text(second[3])
    assert obs1.startswith("<observations") and "done head_act(action='nod'" in obs1 and "upright" in obs1
    assert obs1.endswith("Walk forward a lot.")
    # turn 3's request: turn 2 was interrupted -> trimmed reply (nothing after the cut) and its observations
    third = reqs[2]
    executed2 = third[4]["content"]
    assert third[4]["role"] == "assistant" and executed2.startswith('<move_strides direction="forward" times="6"/>')
    assert "Never spoken" not in executed2
    obs2 = _text(third[5])
    assert "interrupted move_strides" in obs2 and "interrupted: the user interrupted" in obs2
    assert obs2.endswith("What do you see?")
    # ReAct: the capture's observations come back at once, with the photo as an image part
    fourth = reqs[3]
    assert fourth[-2] == {"role": "assistant", "content": "Let me look.<capture/>"}
    parts = fourth[-1]["content"]
    assert isinstance(parts, list) and parts[0]["type"] == "text" and 'step="1/3"' in parts[0]["text"]
    assert parts[1]["type"] == "image_url" and parts[1]["image_url"]["url"].startswith("data:image/png;base64,")
    # the third request of turn 3 is the last allowed (max-steps 3); the turn then ends
    assert 'step="2/3"' in _text(reqs[4][-1])

    doc = json.loads((out / "transcript.json").read_text(encoding="utf-8"))
    assert [len(t["steps"]) for t in doc["turns"]] == [1, 1, 3]
    assert doc["turns"][1]["interrupted"] and not doc["turns"][0]["interrupted"]
    assert "Never spoken" in doc["turns"][1]["steps"][0]["received"]
    assert (out / "turn_03" / "step_1" / "capture_1.png").exists()
    assert (out / "turn_01" / "step_1" / "timeline.json").exists()


@pytest.mark.realtime
def test_interrupt_cancels_the_llm_stream_and_trims_the_reply(fake_llm: FakeLLM, tmp_path: Path) -> None:  # noqa: F811
    """Realtime board: ``--- interrupt-after 1`` cuts a reply still streaming; the server sees the client go."""
    from support.fake_llm import chunk, sse

    def respond(h: Handler, fake: FakeLLM) -> None:
        if len(fake.requests) > 1:
            replay(stream_body(["Stopped."]))(h, fake)
            return
        h.start_sse()
        h.write_piece(sse(chunk("", role="assistant")))
        for i in range(200):  # ~10 s of reply at the server's own pace (a slow model)
            if not h.write_piece(sse(chunk(f"Sentence {i}. "))):
                return
            time.sleep(0.05)
        h.write_piece(sse(chunk(None, finish="stop")))
        h.write_piece(b"data: [DONE]\n\n")
        h.end_chunked()

    fake_llm.responder = respond
    (tmp_path / "turns.txt").write_text("--- interrupt-after 1\nTalk a lot.\n---\nStop.\n", encoding="utf-8")
    rc = cli_main(["chat", "--llm", "openai:test-model", "--base-url", fake_llm.base_url, "--api-key", "k",
                   "--turns", str(tmp_path / "turns.txt"), "--realtime", "--no-live", "--out", str(tmp_path / "c")])
    assert rc == 0
    assert fake_llm.disconnected.wait(10), "the LLM stream was not cancelled"
    second = fake_llm.requests[1]["json"]["messages"]
    executed = second[2]["content"]
    assert second[2]["role"] == "assistant" and executed.startswith("Sentence 0.")
    assert "Sentence 150." not in executed  # only what was spoken before the cut
    doc = json.loads((tmp_path / "c" / "transcript.json").read_text(encoding="utf-8"))
    assert doc["turns"][0]["interrupted"]
