"""A multi-turn conversation with the robot (the paper's Figure 2 loop) on one :class:`RobotSession`.

History (``messages``, OpenAI chat format):

1. ``system``: the code-as-prompt of the mounted vocabulary, the ``<observe/>``
   function and the saved skills (refreshed before every request, so a skill
   saved in one turn is listed in the next);
2. per user turn: the ``user`` message, then per ReAct step the ``assistant``
   reply **as it was executed** (:attr:`TurnResult.executed_text`: an
   interrupted step keeps only what was spoken and dispatched before the cut)
   and the step's observations (:mod:`host.chat.observations`) as a ``user``
   message. Consecutive user-side messages are merged into one (the
   observations of the last step and the next user turn), because many chat
   templates require alternating roles.

ReAct: when an executed reply looked (a ``capture`` call or ``<observe/>``),
the observations go back at once and the model continues, up to ``max_steps``
requests per user turn. :meth:`Conversation.interrupt` (a new user message, or
``interrupt-after``) cuts the running step: the LLM stream is cancelled, the
dispatched calls are interrupted (reset, smooth stop), no further step runs.
An event whose policy is ``interrupt`` (:mod:`host.run.events`: a fall, a
scripted event, ...) cuts the step the same way, and the LLM is asked again at
once with the event in the observations (a further step of the same turn).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import anyio

from host.chat.observations import observation_message
from host.ghost.base import Ghost
from host.run.robot_session import RobotSession, TurnResult
from host.shell.parser import ParseError
from host.shell.registry import RegistryError
from host.shell.types import Module

#: functions whose call in a reply asks for the observations before the turn ends
LOOK_FUNCTIONS = ("observe", "capture")

Message = dict[str, Any]
GhostFactory = Callable[[], Ghost | None]


def observe_module() -> Module:
    """``<observe/>``: ask for the observations so far and continue after them."""

    async def observe() -> str:
        """End your reply with this to look: once everything in the reply has run, its results (and any
        photo) come back to you as the next message and you continue. Use it when what you do next
        depends on what happened; `capture` does the same."""
        return "observations will be sent back"

    return Module.from_functions("observe", observe, channel="observe", doc="looking at the results")


@dataclass
class StepRecord:
    """One LLM request and what it did."""

    step: int
    received: str
    executed: str
    interrupted: bool
    outcome: str
    out: str
    observation: str
    looked: bool
    stream_error: str | None = None  # the LLM stream failed (provider/network error), else None


@dataclass
class TurnRecord:
    """One user turn."""

    index: int
    user: str
    steps: list[StepRecord] = field(default_factory=list)
    interrupted: bool = False


class Conversation:
    """The chat loop on ``session``; ``ghost`` makes the LLM for each request."""

    def __init__(self, session: RobotSession, ghost: GhostFactory, *, max_steps: int = 4, vision: bool = False,
                 real_llm: bool = False, settle_s: float = 0.3) -> None:
        if max_steps < 1:
            raise ValueError(f"max_steps must be >= 1, got {max_steps}")
        self.session = session
        self.ghost = ghost
        self.max_steps = max_steps
        self.vision = vision
        self.real_llm = real_llm
        self.settle_s = settle_s
        self.messages: list[Message] = [{"role": "system", "content": ""}]
        self.turns: list[TurnRecord] = []
        self._cut = False
        self._acting = False
        try:
            session.shell.registry.mount(observe_module())
        except RegistryError:  # already mounted on this session
            pass

    # -- history -----------------------------------------------------------------------------
    def _system(self) -> None:
        self.messages[0] = {"role": "system", "content": self.session.prompt(format="xml")}

    def _user(self, msg: Message) -> None:
        last = self.messages[-1]
        if last["role"] != "user":
            self.messages.append(msg)
            return
        parts = _parts(last["content"]) + _parts(msg["content"])
        if all(p["type"] == "text" for p in parts):
            last["content"] = "\n\n".join(p["text"] for p in parts)
        else:
            last["content"] = parts

    # -- turns -------------------------------------------------------------------------------
    @property
    def acting(self) -> bool:
        """True while a user turn is running."""
        return self._acting

    def interrupt(self) -> int:
        """Cut the running turn (external event); returns the number of calls cancelled."""
        if not self._acting:
            return 0
        self._cut = True
        return self.session.interrupt()

    async def turn(self, user: str, *, interrupt_after: float | None = None) -> TurnRecord:
        """Run one user turn (up to ``max_steps`` LLM requests).

        ``interrupt_after``: board seconds after the turn started at which it is
        interrupted. A ghost with an ``interrupt_after`` attribute (a scripted
        reply from a ``--- interrupt-after S`` block) interrupts its own step.
        The ghost factory may return None (no more scripted replies): the turn ends.
        """
        record = TurnRecord(len(self.turns) + 1, user)
        self.turns.append(record)
        self._user({"role": "user", "content": user})
        self._cut, self._acting = False, True
        runtime = self.session.runtime
        try:
            async with anyio.create_task_group() as tg:
                if interrupt_after is not None:
                    tg.start_soon(self._interrupt_at, runtime.board_now_s() + interrupt_after)
                for step in range(1, self.max_steps + 1):
                    self._system()
                    ghost = self.ghost()
                    if ghost is None:
                        break
                    cut = getattr(ghost, "interrupt_after", None)
                    turn = await self.session.run_turn(
                        ghost.stream(list(self.messages)), label=f"turn {record.index} step {step}",
                        out=self.session.out / f"turn_{record.index:02d}" / f"step_{step}", hold=self.real_llm,
                        interrupt_after=cut, settle_s=self.settle_s)
                    looked = any(r.function in LOOK_FUNCTIONS and r.start is not None for r in turn.result.timeline)
                    obs = self._after_step(record, step, turn, looked)
                    if turn.interrupted_by is not None and not self._cut and step < self.max_steps:
                        continue  # the world interrupted: ask again at once, with the event observed
                    if turn.interrupted or self._cut:
                        record.interrupted = True
                        break
                    if not looked or step == self.max_steps:
                        if looked:
                            obs["content"] = _note(obs["content"], f"step limit reached ({self.max_steps} steps per turn)")
                        break
                tg.cancel_scope.cancel()
        finally:
            self._acting = False
        return record

    def _after_step(self, record: TurnRecord, step: int, turn: TurnResult, looked: bool) -> Message:
        if turn.executed_text:
            self.messages.append({"role": "assistant", "content": turn.executed_text})
        obs = observation_message(turn, step=step, max_steps=self.max_steps, vision=self.vision)
        self._user(obs)
        text = obs["content"] if isinstance(obs["content"], str) else obs["content"][0]["text"]
        err = turn.result.error
        stream_error = None if err is None or isinstance(err, ParseError) else str(err)
        record.steps.append(StepRecord(step, turn.received_text, turn.executed_text, turn.interrupted,
                                       turn.summary.outcome, str(turn.out), text, looked, stream_error))
        return self.messages[-1]

    async def _interrupt_at(self, at_s: float) -> None:
        await self.session.runtime.streamer.wait_board_time(int(at_s * 1e6))
        self.interrupt()

    # -- transcript --------------------------------------------------------------------------
    def transcript(self) -> dict[str, Any]:
        """History and per-turn records (images replaced by a placeholder)."""
        return {"messages": [_no_images(m) for m in self.messages], "turns": [asdict(t) for t in self.turns]}

    def write_transcript(self, path: Path) -> None:
        """Write :meth:`transcript` as UTF-8 JSON."""
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.transcript(), ensure_ascii=False, indent=1), encoding="utf-8")


def _parts(content: Any) -> list[dict[str, Any]]:
    return [{"type": "text", "text": content}] if isinstance(content, str) else list(content)


def _note(content: Any, note: str) -> Any:
    if isinstance(content, str):
        head, sep, tail = content.rpartition("\n</observations>")
        return f"{head}\nnote: {note}{sep}{tail}" if sep else content
    return content


def _no_images(m: Message) -> Message:
    if isinstance(m["content"], str):
        return dict(m)
    return {**m, "content": [p if p.get("type") != "image_url" else {"type": "image_url", "image_url": "<png omitted>"}
                             for p in m["content"]]}
