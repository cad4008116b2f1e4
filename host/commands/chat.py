"""``ghostshell chat``: a conversation with the robot, interactive or batch, on one board and one shell.

* interactive (no ``--turns``/``--replies``): type a message and press Enter;
  the live channel view runs meanwhile. A message typed while the robot acts
  interrupts the turn (LLM stream cancelled, calls stopped smoothly) and starts
  the next. With ``--llm scripted`` what you type is executed as the reply.
* batch: ``--turns FILE`` (user turns for a real LLM) and/or ``--replies FILE``
  (assistant replies replayed one per LLM request with ``--llm scripted``);
  blocks separated by a line ``---``; ``--- interrupt-after S`` interrupts the
  next block's turn S board seconds after it starts.

Artefacts: ``<out>/turn_NN/step_K/`` per LLM request (timeline, joints,
summary), ``<out>/transcript.json`` (history and per-step records), the frame
logs of the session in ``<out>``.

Ctrl-C (or SIGTERM) ends the conversation (:mod:`host.run.stops`): the running turn is
interrupted as a typed message interrupts it, the robot goes to its rest pose, the transcript and
every step's artefacts are written, one line, exit 130; a second Ctrl-C stops at once. A turn that
reaches ``--max-board-s``, or frame logs that reach ``--max-log-mb``, end it the same way (exit 1).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from host.commands.errors import print_error
from host.ghost.factory import LLM_SPECS_HELP
from host.commands.outarg import EarlierRun, out_dir_problem, session_start_files
from host.commands.run import _push_text, add_run_options, check_run_args, line_rates, resolve_strict, servo_bus_of


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--llm", default="scripted", metavar="SPEC",
                        help=f"{LLM_SPECS_HELP}, or scripted (replay --replies)")
    parser.add_argument("--base-url", default=None, metavar="URL", help="LLM endpoint (else GHOSTSHELL_LLM_BASE_URL/OPENAI_BASE_URL)")
    parser.add_argument("--api-key", default=None, metavar="KEY", help="LLM key (else GHOSTSHELL_LLM_API_KEY/OPENAI_API_KEY)")
    parser.add_argument("--turns", metavar="FILE", help="user turns, separated by lines '---' (batch mode)")
    parser.add_argument("--replies", metavar="FILE", help="assistant replies for --llm scripted, separated by '---'")
    parser.add_argument("--max-steps", type=int, default=4, metavar="N",
                        help="LLM requests per user turn when replies look (capture, <observe/>) (default 4)")
    parser.add_argument("--vision", action="store_true", help="send camera photos to the model as image parts")
    add_run_options(parser)


def _read(path: str, option: str) -> str:
    """The text of ``path`` (given with ``option``); :class:`host.commands.inputs.InputError` (one line)
    when it is missing, unreadable, not UTF-8 or empty."""
    from host.commands.inputs import read_text_input

    return read_text_input(path, option, what="user turns" if option == "--turns" else "replies")


def main(args: argparse.Namespace) -> int:
    import anyio

    from host.chat.script import ScriptError, parse_blocks
    from host.ghost import GhostError
    from host.link import LinkError
    from host.shell.skills import SkillError, SkillStore, skills_path

    if args.max_steps < 1:
        print_error("chat", "--max-steps must be >= 1")
        return 2
    from host.ghost.factory import check_spec

    try:  # the spec's form first: 'scripted:x' was read as a real LLM ("--replies needs --llm scripted")
        args.llm = check_spec(args.llm)  # ' Scripted' as the conversation reads it
    except GhostError as e:
        print_error("chat", str(e))
        return 2
    scripted = args.llm == "scripted"
    try:
        turns = parse_blocks(_read(args.turns, "--turns")) if args.turns else None
        replies = parse_blocks(_read(args.replies, "--replies")) if args.replies else None
        skills = SkillStore(skills_path(args.skills))
    except (OSError, ValueError, ScriptError, SkillError) as e:  # InputError is a ValueError
        print_error("chat", str(e))
        return 2
    if replies is not None and not scripted:
        print_error("chat", "--replies needs --llm scripted")
        return 2
    if scripted and turns is not None and replies is None:
        print_error("chat", "--llm scripted replays --replies FILE; for --turns use --llm openai:MODEL")
        return 2
    if replies is not None and not replies:
        print_error("chat", f"{args.replies} holds no reply (blocks are separated by lines '---')")
        return 2
    if turns is not None and not turns:
        print_error("chat", f"{args.turns} holds no turn (blocks are separated by lines '---')")
        return 2
    if turns is not None and replies is not None and len(turns) > len(replies):
        print_error("chat", f"{len(turns)} turns in {args.turns} but only {len(replies)} replies in {args.replies}; "
              "every turn needs at least one reply")
        return 2
    if not scripted:
        from host.ghost import make_ghost

        try:
            make_ghost(args.llm, base_url=args.base_url, api_key=args.api_key)  # bad spec/no key: once, up front
        except GhostError as e:
            print_error("chat", str(e))
            return 2
    from host.commands.linkarg import link_exit_status

    status = check_run_args(args)
    if status is not None:
        return status
    from host.shell.limits import TurnLimits

    for name, blocks in (("--replies", replies), ("--turns", turns)):
        for i, block in enumerate(blocks or [], 1):
            why = TurnLimits().refuse_reply(block.text) if name == "--replies" else None
            if why is not None:  # refused before the board starts, not cut minutes into the turn
                print_error("chat", f"{name} {args.replies}: reply {i}: {why}; nothing was run")
                return 2
    out = Path(args.out) if args.out else Path("runs") / "chat"
    why = None if args.out else out_dir_problem(out)  # a given --out was checked when it was parsed
    if why is not None:
        print_error("chat", f"the run folder {out} {why}; give another with --out DIR")
        return 2
    try:
        return anyio.run(_chat, args, turns, replies, skills, out, backend="asyncio")
    except (LinkError, GhostError, SkillError, RuntimeError, OSError) as e:
        print_error("chat", str(e))
        return link_exit_status(e)


@dataclass
class _Chat:
    """What the stop handler needs to see of a conversation in progress."""

    session: Any
    conv: Any = None
    loop: Any = None  # the conversation loop's cancel scope: cancelled by a stop while no turn runs
    rested: bool | None = None
    line_refused: bool = False  # a typed line over MAX_LINE ended the input: exit status 2

    def on_first_stop(self, stop: Any) -> bool:
        """A first Ctrl-C / SIGTERM (or a bound): interrupt the running turn (as a typed message does) or
        leave the wait for input; the conversation then ends at the rest pose."""
        graceful = self.session.request_stop(stop)
        if self.conv is not None and self.conv.acting:
            self.conv.interrupt()
        elif self.loop is not None:
            self.loop.cancel()
        return graceful


async def _chat(args: argparse.Namespace, turns: Any, replies: Any, skills: Any, out: Path) -> int:
    from host.link import LinkError
    from host.run.robot_session import RobotSession, SessionOptions
    from host.run.stops import StopSignals

    baud, wire_baud = line_rates(args)
    opts = SessionOptions(robot=str(args.robot_value.root), robots_dir=args.robots_dir, vocabulary=args.vocabulary,
                          mode=args.mode, strict=resolve_strict(args), lockstep=args.lockstep, link=args.link,
                          emulate_board=args.emulate_board or None, baud=baud, wire_baud=wire_baud,
                          out=out, skills=skills,
                          task_label="chat", scene=args.scene, policy=getattr(args, "loaded_policy", None),
                          faults=args.faults, fault_seed=args.fault_seed, foxglove=args.foxglove,
                          servo_bus=servo_bus_of(args),
                          mcp_mounts=tuple(args.mount_mcp),
                          event_policy=getattr(args, "event_policy", None),
                          events=getattr(args, "scripted_events", ()),
                          pushes=tuple(_push_text(p) for p in args.push), max_board_s=args.max_board_s,
                          max_log_mb=args.max_log_mb, plots=not args.no_plots)
    session = RobotSession(opts)
    chat = _Chat(session)
    signals = StopSignals(chat.on_first_stop, session.abort_cleanups)
    transcript = out / "transcript.json"
    earlier = EarlierRun(out, only=session_start_files())  # the files the start overwrites: back if it is refused
    try:
        try:
            async with signals.guard(), session:
                earlier.discard()  # the session began: its own files replace them
                await _converse(args, chat, turns, list(replies or []), transcript)
        finally:
            earlier.restore()  # refused or stopped before the session began (a no-op once it began)
    except LinkError:
        if signals.forced is None:
            raise
    conv = chat.conv
    if signals.forced is not None:  # stopped at once: the step in progress and the transcript, no plots
        interrupted = signals.interrupted()
        # the step in progress, if one was (between steps there is none: no empty report beside the turns)
        ended = session.ended_turn(interrupted) if session.turn_running else None
        if ended is not None:
            session.write_now(ended, plots=False)
        if conv is not None:
            conv.write_transcript(transcript)
        what = "transcript and artefacts" if conv is not None else "no turn began; the frame logs"
        print_error("chat", f"{interrupted.how}; {what} in {out}/")
        return 130
    stop = signals.reported(session.stop)
    if stop is not None:
        rest = ("the chat had already ended" if chat.rested is None else
                f"the robot went to its rest pose {session.robot.rest_pose!r}" if chat.rested else
                "the robot could not be brought to its rest pose")
        n = len(conv.turns) if conv is not None else 0
        print_error("chat", f"{stop.message} after {n} turn{'s' if n != 1 else ''}; {rest}; "
              f"transcript and artefacts in {out}/")
        return int(stop.exit_status)
    print(f"transcript and artefacts in {out}/")
    if chat.line_refused:
        return 2
    steps = [s for t in conv.turns for s in t.steps] if conv is not None else []
    if steps and all(s.stream_error for s in steps):
        print_error("chat", f"every LLM request failed ({steps[-1].stream_error})")
        return 1
    return 0


async def _converse(args: argparse.Namespace, chat: _Chat, turns: Any, pending: list[Any], transcript: Path) -> None:
    """The conversation on a started session (``chat.conv``); after a stop, the robot goes to its rest pose."""
    import anyio

    from host.chat.conversation import Conversation
    from host.ghost import make_ghost
    from host.ghost.base import Ghost

    session = chat.session
    scripted = args.llm == "scripted"
    interactive = turns is None and not pending
    typed: list[str] = []  # interactive scripted: the typed line is the reply

    def ghost() -> Ghost | None:
        if scripted:
            if interactive:
                program = typed.pop(0) if typed else None
                if program is None:
                    return None
                return make_ghost("scripted", program=program, tokens_per_s=args.tokens_per_s, seed=args.seed,
                                  sleep=session.pacer())
            if not pending:
                return None
            block = pending.pop(0)
            g = make_ghost("scripted", program=block.text, tokens_per_s=args.tokens_per_s, seed=args.seed,
                           sleep=session.pacer())
            g.interrupt_after = block.interrupt_after  # type: ignore[attr-defined]
            return g
        return make_ghost(args.llm, base_url=args.base_url, api_key=args.api_key)

    conv = chat.conv = Conversation(session, ghost, max_steps=args.max_steps, vision=args.vision,
                                    real_llm=not scripted)
    if not args.no_live and sys.stdout.isatty():
        from host.run.live import live_view

        session.background().start_soon(live_view, session.shell, session.runtime, "chat")
    with anyio.CancelScope() as chat.loop:
        if session.stop is not None:  # stopped while the session started
            pass
        elif interactive:
            chat.line_refused = await _interactive(conv, typed if scripted else None)
        elif turns is not None:
            for block in turns:
                rec = await conv.turn(block.text, interrupt_after=block.interrupt_after)
                _print_turn(rec)
                conv.write_transcript(transcript)
                if session.stop is not None:
                    break
        else:
            n = 0
            while pending and session.stop is None:
                n += 1
                rec = await conv.turn(f"(turn {n})")
                _print_turn(rec)
                conv.write_transcript(transcript)
    chat.loop = None
    if session.stop is not None:
        chat.rested = await session.go_to_rest()
    conv.write_transcript(transcript)


def _print_turn(rec: Any) -> None:
    print(f"--- turn {rec.index}{' (interrupted)' if rec.interrupted else ''}: {rec.user[:70]}")
    for s in rec.steps:
        print(f"  step {s.step} [{s.outcome}] executed: {s.executed[:200]}")
        for line in s.observation.splitlines()[1:-1]:
            print(f"    {line}")


async def _interactive(conv: Any, typed: list[str] | None) -> bool:
    """Read lines from stdin; a line that arrives while the robot acts interrupts the turn. A line over
    :data:`host.bounded_read.MAX_LINE` characters (``/dev/zero`` piped in) is refused with one line and
    ends the input, as its end does; returns whether that happened."""
    import anyio
    import anyio.to_thread

    from host.bounded_read import MAX_LINE

    send, recv = anyio.create_memory_object_stream[str | None](16)
    refused: list[bool] = []

    async def reader() -> None:
        while True:
            line = await anyio.to_thread.run_sync(sys.stdin.readline, MAX_LINE + 1, abandon_on_cancel=True)
            if len(line) > MAX_LINE:
                print_error("chat", f"a line of standard input is longer than {MAX_LINE} characters; "
                            "input ended there (type shorter messages)")
                refused.append(True)
                await send.send(None)
                return
            if not line:
                await send.send(None)
                return
            if line.strip():
                await send.send(line.rstrip("\n"))

    async with anyio.create_task_group() as tg:
        tg.start_soon(reader)
        print("chat: type a message (Ctrl-D to end); typing while the robot acts interrupts it", flush=True)
        nxt: str | None = await recv.receive()
        while nxt is not None:
            line, nxt = nxt, None
            if typed is not None:
                typed.append(line)
            done = anyio.Event()
            got: list[str | None] = []

            async def run_turn(text: str) -> None:
                rec = await conv.turn(text if typed is None else f"(typed reply) {text[:60]}")
                _print_turn(rec)
                done.set()

            async with anyio.create_task_group() as turn_tg:
                turn_tg.start_soon(run_turn, line)

                async def watch() -> None:
                    with anyio.CancelScope() as scope:
                        watching.append(scope)
                        got.append(await recv.receive())
                        if got[-1] is not None:  # a new line interrupts; end of input lets the turn finish
                            conv.interrupt()

                watching: list[anyio.CancelScope] = []
                turn_tg.start_soon(watch)
                await done.wait()
                for scope in watching:
                    scope.cancel()
            if conv.session.stop is not None:  # Ctrl-C (or a bound) ended the conversation
                break
            if got:
                nxt = got[0]
            else:
                nxt = await recv.receive()
        tg.cancel_scope.cancel()
    return bool(refused)
