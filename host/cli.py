"""The ``ghostshell`` command: a thin dispatcher over :mod:`host.commands`.

Each subcommand lives in its own module under ``host/commands`` exposing
``configure(parser: argparse.ArgumentParser) -> None`` and
``main(args: argparse.Namespace) -> int``. Modules are imported only when their
subcommand runs, so ``ghostshell --help`` stays fast and one broken optional
dependency cannot take down every command.

Exit status, the same in every command (:data:`EXIT_CODES`; ``tests/cli/test_exit_codes.py``
checks each command): 0 success, 1 the run or operation failed, 2 usage or bad input (every
argument is checked before anything starts: one line says what is wrong and what would be right),
130 interrupted (Ctrl-C or SIGTERM). Every error line reads ``ghostshell COMMAND: message``
(:func:`host.commands.errors.print_error`). ``ghostshell vcan`` passes its COMMAND's status through.
SIGTERM is handled as Ctrl-C is: ``run``, ``demo`` and ``chat`` interrupt their turn
(:mod:`host.run.stops`); elsewhere the command stops, cleans up and exits 130. A command started with
SIGINT ignored (bash starts a script's background job, ``ghostshell demo &``, so; the process inherits
it and Python then installs no KeyboardInterrupt handler) gets Python's default handler back at the
start, so ``kill -INT PID`` interrupts it in every phase (rendering, a tour, a handshake), as Ctrl-C does.
Standard output that cannot be written never stops a command (:mod:`host.commands.stdout_guard`): a reader
that left (``| head -1``) gets nothing more, silently, and the status is the command's own; any other error
(``> /dev/full``) is one line at the end and status 1; a run still writes its artefacts either way.
"""

from __future__ import annotations

import argparse
import importlib
import shutil
import signal
import sys
import textwrap
import threading
from collections.abc import Sequence
from types import FrameType
from typing import NoReturn

from host.commands.errors import print_error
from host.commands.stdout_guard import StdoutGuard

#: subcommand -> (module under host.commands, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "board": ("board", "run the emulated board of a robot (firmware_sim) on a link: pty, a serial port/URL or CAN"),
    "firmware": ("firmware", "build the C firmware for a part (build, targets: flash and RAM budgets), or check a real board answers (check)"),
    "pose": ("pose", "drive the board to a named pose and report the largest error"),
    "estop": ("estop", "emergency-stop the board on a link (ESTOP), or clear an estop / latched watchdog fault (--clear)"),
    "demo": ("demo", "the showcase: a paper task end to end on an emulated board (pty, MuJoCo, scripted LLM)"),
    "tour": ("tour", "start a board (default on a pty) and drive it through the named poses"),
    "log": ("log", "decode a frame log written with --log"),
    "dbc": ("dbc", "print a robot's CAN database (DBC, classic or --fd), or --check/--write the files it checks in"),
    "replay": ("replay", "feed a recorded run's host-to-board traffic into a fresh lockstep board"),
    "prompt": ("prompt", "print the system prompt for the mounted functions"),
    "dsbc": ("dsbc", "score a generated function-token program against a ground truth"),
    "run": ("run", "run a task or a program on the robot"),
    "chat": ("chat", "a multi-turn conversation with the robot (interactive, or batch from files)"),
    "robots": ("robots", "make, list, check and calibrate robots: new NAME --mjcf FILE | list | show NAME | check NAME | path [NAME] | calibrate NAME --servo-bus PORT"),
    "skills": ("skills", "list, show or delete the saved skills (the persistent skill library)"),
    "mcp": ("mcp", "serve the shell as an MCP server (stdio, or streamable HTTP with --http PORT)"),
    "eval": ("eval", "evaluate an LLM the paper's way: DSBC over the tasks, runs on the board, the native-call ablation"),
    "render": ("render", "render run.mp4 for a finished run from its recorded state"),
    "fuzz": ("fuzz", "coverage-guided fuzzing (atheris) of the decoder, board, shell and link client"),
    "vcan": ("vcan", "run a command with SocketCAN vcan interfaces up (this kernel, or User-Mode Linux where it has no vcan)"),
}


#: status -> meaning (``ghostshell --help`` prints it; the README's "Exit status" section is the same table)
EXIT_CODES: dict[int, str] = {
    0: "success",
    1: "the run or operation failed (a call failed, the link was lost, the board refused, a bound was reached)",
    2: "usage or bad input: an argument, a file, a link spec or a port that cannot be used (one line says why)",
    130: "interrupted (Ctrl-C or SIGTERM); run, demo and chat still write what ran",
}

#: environment variables the commands read (name -> what it does), listed in ``ghostshell --help``;
#: tests/cli/test_environment_help.py fails while the code reads a ``GHOSTSHELL_*`` variable not named here
ENVIRONMENT: dict[str, str] = {
    "GHOSTSHELL_LLM_BASE_URL": "LLM endpoint when --base-url is not given (else OPENAI_BASE_URL / ANTHROPIC_BASE_URL)",
    "GHOSTSHELL_LLM_API_KEY": "LLM key when --api-key is not given (else OPENAI_API_KEY / ANTHROPIC_API_KEY)",
    "GHOSTSHELL_LLM_MODEL": "model for an --llm spec without one (openai: / anthropic:)",
    "GHOSTSHELL_ROBOTS": "more robot folders to search, separated by ':' (after --robots-dir, before the user's)",
    "GHOSTSHELL_SKILLS": "the skill library file (default in the user data folder)",
    "GHOSTSHELL_BOARD_NICE": "nice increment a realtime emulated board asks for (default -10; 0: unchanged)",
    "GHOSTSHELL_HOST_NICE": "nice value a realtime run's host lowers itself to where permitted (default -10)",
    "GHOSTSHELL_STALLS": "test hook: 'seed=N,p=P,max_s=S' stalls the host's control path at random (lockstep identity tests)",
    "GHOSTSHELL_BOARD_KERNEL": "the emulated board's per-tick servo path: native (default), native! or python",
    "GHOSTSHELL_LOCKSTEP_OVERLAP": "1: a lockstep board does its link work while the C kernel ticks on its own thread, not after each run of ticks (A/B; off by default: slower on 2 cores)",
    "GHOSTSHELL_MJCF_CHECK_CACHE": "folder for recorded robot-model checks ('off': check every time)",
    "GHOSTSHELL_NATIVE_CACHE": "folder for the board's compiled per-tick library (default: the user cache)",
    "GHOSTSHELL_CFIRMWARE_CACHE": "folder for the built C firmware (default: the user cache)",
    "GHOSTSHELL_MJ_TIMERS": "1 keeps MuJoCo's stage timers running beside the native tick (profiling)",
    "MUJOCO_GL": "MuJoCo's offscreen renderer for the video and the board's camera: egl (the default) or osmesa",
}

DESCRIPTION = ("GhostShell: an LLM drives a robot while it is still talking. Its streamed function tokens run "
               "through the shell onto the robot's emulated board (MuJoCo) or a real one, over a serial link or CAN.")


class OneLineParser(argparse.ArgumentParser):
    """An argparse parser whose usage error is one line on stderr, exit status 2: ``PROG: error: WHY
    (PROG --help: usage)``, without argparse's usage block before it (17 lines for ``ghostshell run``,
    which hid the line that says what was wrong). Its subcommands' parsers are of the same class."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} ({self.prog} --help: usage)\n")

    def parse_args(self, args: Sequence[str] | None = None,  # type: ignore[override]
                   namespace: argparse.Namespace | None = None) -> argparse.Namespace:
        """As argparse's, but an unknown option is reported by the subcommand's parser, so its line names
        that command (``ghostshell run: error: unrecognized arguments: --bogus``), not ``ghostshell``."""
        ns, extra = self.parse_known_args(args, namespace)
        if extra:
            owner: argparse.ArgumentParser = getattr(ns, "_parser", self)
            owner.error("unrecognized arguments: " + " ".join(extra))
        return ns


def build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    """Build the top-level parser; only the chosen subcommand's module is imported."""
    status = "exit status: " + "; ".join(f"{k} {v}" for k, v in EXIT_CODES.items()) + \
        " (ghostshell vcan: its COMMAND's status)."
    width = max(40, min(shutil.get_terminal_size().columns, 100) - 2)
    env = [f"  {name}\n" + textwrap.fill(what, width, initial_indent=" " * 6, subsequent_indent=" " * 6)
           for name, what in ENVIRONMENT.items()]
    epilog = textwrap.fill(status, width) + "\n\nenvironment:\n" + "\n".join(env)
    parser = OneLineParser(prog="ghostshell", description=textwrap.fill(DESCRIPTION, width), epilog=epilog,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    chosen = next((a for a in argv if not a.startswith("-")), None)
    for name, (module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == chosen:
            mod = importlib.import_module(f"host.commands.{module}")
            mod.configure(p)
            p.set_defaults(_main=mod.main, _parser=p)
    return parser


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the command runs, as Ctrl-C raises KeyboardInterrupt."""


def _on_sigterm(signum: int, frame: FrameType | None) -> None:
    raise Terminated()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the ``ghostshell`` command ``argv`` (default ``sys.argv[1:]``); returns its exit status (the console
    script calls :func:`entry`, which calls this).

    Standard output that cannot be written never stops the command (:class:`host.commands.stdout_guard.StdoutGuard`):
    a reader that left (``| head -1``) drops the rest silently and the status is the command's; any other error
    (``> /dev/full``) is one line on stderr at the end and status 1 unless the command already failed."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    command = next((a for a in args_list if not a.startswith("-")), "")
    name = command if command in COMMANDS else None
    guard = StdoutGuard.install()
    if guard is None:
        return _main(args_list, command)
    try:
        status = _main(args_list, command)
    except SystemExit as e:  # argparse: --help (0) or a usage error (2)
        if e.code is not None and not isinstance(e.code, int):
            guard.finish(name, 1)
            raise
        raise SystemExit(guard.finish(name, e.code or 0)) from None
    except BaseException:
        guard.finish(name, 1)
        raise
    return guard.finish(name, status)


def _main(args_list: list[str], command: str) -> int:
    """:func:`main` without the stdout guard."""
    previous = signal.getsignal(signal.SIGTERM)
    previous_int = signal.getsignal(signal.SIGINT)
    in_main_thread = threading.current_thread() is threading.main_thread()  # else leave signals alone
    if in_main_thread:
        signal.signal(signal.SIGTERM, _on_sigterm)
        if previous_int == signal.SIG_IGN:  # a background job of a script (`ghostshell demo &`): see below
            signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        parser = build_parser(args_list)
        args = parser.parse_args(args_list)
        return int(args._main(args) or 0)
    except KeyboardInterrupt as e:  # Ctrl-C or SIGTERM where the command has no handling of its own
        what = "SIGTERM" if isinstance(e, Terminated) else "SIGINT (Ctrl-C)"
        print_error(command if command in COMMANDS else None, f"interrupted by {what}")
        return 130
    except ImportError as e:  # Ctrl-C while an extension module initialises (seen: ``import mujoco``)
        interrupt = _interrupt_behind(e)
        if interrupt is None:
            raise
        what = "SIGTERM" if isinstance(interrupt, Terminated) else "SIGINT (Ctrl-C)"
        print_error(command if command in COMMANDS else None, f"interrupted by {what}")
        return 130
    except UnicodeDecodeError as e:  # a file the command read is not UTF-8: one clear line, not a traceback
        print_error(command if command in COMMANDS else None,
                    f"an input file is not UTF-8 text ({e.reason} at byte {e.start})")
        return 2
    finally:
        if in_main_thread:
            signal.signal(signal.SIGTERM, previous if previous is not None else signal.SIG_DFL)
            if previous_int == signal.SIG_IGN:
                signal.signal(signal.SIGINT, signal.SIG_IGN)


def _interrupt_behind(error: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (Ctrl-C, or SIGTERM as :class:`Terminated`) an error was raised while
    handling, if any: a C extension whose initialisation a signal cut short reports ``ImportError:
    initialization failed`` with the KeyboardInterrupt as its context."""
    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return e
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return None


def entry() -> int:
    """The ``ghostshell`` console script and ``python -m host``: :func:`main`; then SIGINT and SIGTERM are
    ignored while the interpreter shuts down (~150 ms). The command has finished and printed its last
    line by then; a Ctrl-C there used to kill the process by the signal (a shell shows 130 after a run
    that succeeded). Ignored rather than handled: Python puts the handlers it installed back to the
    default before it unloads its modules, so a handler would cover only the first moments."""
    status = main()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, signal.SIG_IGN)
    return status


if __name__ == "__main__":
    sys.exit(entry())
