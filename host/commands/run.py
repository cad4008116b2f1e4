"""``ghostshell run``: a task, a program or an LLM prompt on the robot, end to end.

With ``--link pty`` (default) it starts the emulated board itself. It shows the
channels live (on a terminal) and leaves timeline.json/png, joints.png,
summary.json, both frame logs and run.mcap (:mod:`host.run.mcap_log`) in ``--out``;
with ``--video`` also run.mp4 with its sound (rendered after the run, see
:mod:`host.run.video`); with ``--foxglove [PORT]`` Foxglove can watch the run live
(:mod:`host.run.foxglove_live`).

Ctrl-C (or SIGTERM) interrupts the run: the turn is cut through the lifecycle tree, the robot goes
to its rest pose, every artefact is written, one line says so, exit status 130; a second Ctrl-C
stops at once (summary.json and timeline.json still written). ``--max-board-s`` / ``--max-log-mb``
bound a run the same way (exit status 1). See :mod:`host.run.stops`.
"""

from __future__ import annotations

import argparse
import os
import stat
import sys
from pathlib import Path

from host.commands.modearg import add_mode_argument
from host.commands.errors import command_of, print_error
from host.ghost.factory import LLM_SPECS_HELP
from host.commands.inputs import STDIN, InputError, baud_rate, read_text_input
from host.commands.linkarg import USAGE_STATUS, add_link_argument, link_exit_status, preflight_link, unreachable_link
from host.commands.outarg import (EarlierRun, add_no_plots_argument, out_dir, out_dir_problem,
                                  remove_unused_out, tcp_port_taken)
from host.commands.robotarg import add_robot_argument, robot_from_args
from host.run.stops import DEFAULT_MAX_BOARD_S, DEFAULT_MAX_LOG_MB
from robots.description import Robot
from protocol.cliargs import push_arg, seed_arg
from protocol.linkkinds import link_kind


def configure(parser: argparse.ArgumentParser) -> None:
    # not required=True: argparse would then report a missing source before an unknown flag (checked in main)
    src = parser.add_mutually_exclusive_group()
    src.add_argument("--task", type=int, metavar="N",
                     help="one of the robot's tasks (ghostshell robots show NAME): replay its ground-truth tokens")
    src.add_argument("--xml", metavar="TEXT", help="function tokens to replay, e.g. '<head_act action=\"nod\"/>'")
    src.add_argument("--xml-file", metavar="F", help="a file of function tokens to replay (- reads standard input)")
    src.add_argument("--prompt", metavar="TEXT", help="an instruction for a real LLM (needs --llm PROVIDER:MODEL)")
    parser.add_argument("--video", action="store_true", help="also render run.mp4 after the run (MuJoCo offscreen, ffmpeg)")
    add_run_options(parser, clears_out=True)
    parser.add_argument("--llm", default="scripted", metavar="SPEC",
                        help=f"scripted (replay, default) or {LLM_SPECS_HELP}")
    parser.add_argument("--base-url", default=None, metavar="URL",
                        help="LLM endpoint (else GHOSTSHELL_LLM_BASE_URL/OPENAI_BASE_URL)")
    parser.add_argument("--api-key", default=None, metavar="KEY",
                        help="LLM key (else GHOSTSHELL_LLM_API_KEY/OPENAI_API_KEY)")
    parser.add_argument("--interrupt-at", type=_non_negative, default=None, metavar="S",
                        help="interrupt the run S board seconds after the stream starts (external event)")


def add_run_options(parser: argparse.ArgumentParser, *, clears_out: bool = False) -> None:
    """Options shared by ``run``, ``demo`` and ``chat``; ``clears_out``: the command removes an earlier run's
    artefacts from ``--out`` (:func:`run_with`), and its help says so."""
    add_robot_argument(parser)
    parser.add_argument("--vocabulary", default=None, metavar="NAME",
                        help="the robot's vocabulary shown in the prompt (default: the robot's; the mapper accepts "
                             "all of them; ghostshell robots show NAME lists them)")
    add_link_argument(parser)
    parser.add_argument("--emulate-board", action="store_true",
                        help="start the emulated board on --link first (implied for pty and can:slcan:pty)")
    clock = parser.add_mutually_exclusive_group()
    clock.add_argument("--lockstep", dest="lockstep", action="store_true",
                       help="virtual board clock, as fast as the host streams (reproducible)")
    clock.add_argument("--realtime", dest="lockstep", action="store_false", help="wall-clock board (default)")
    parser.set_defaults(lockstep=False)
    add_mode_argument(parser)
    parsing = parser.add_mutually_exclusive_group()
    parsing.add_argument("--lenient", dest="strict", action="store_false",
                         help="recover from malformed output with warnings (default with a real --llm)")
    parsing.add_argument("--strict", dest="strict", action="store_true",
                         help="stop at the first malformed tag (the paper's parser; default for scripted replay)")
    parser.set_defaults(strict=None)
    parser.add_argument("--skills", default=None, metavar="FILE",
                        help="skill library file (else $GHOSTSHELL_SKILLS, else the user data directory)")
    parser.add_argument("--tokens-per-s", type=_positive, default=30.0, metavar="N",
                        help="scripted LLM speed (default 30)")
    parser.add_argument("--seed", type=int, default=0, metavar="N", help="scripted LLM jitter seed")
    parser.add_argument("--baud", type=baud_rate, default=None, metavar="N",
                        help="the serial line's rate in bit/s: a real port opens at it (default 115200); the "
                             "emulated board over a pty models its wire time at it, as `ghostshell board --baud` "
                             "does (default: not modelled, a pty is as fast as the machine)")
    parser.add_argument("--out", type=out_dir, default=None, metavar="DIR",
                        help="artefact folder (default runs/<label>" + ("; an earlier run's artefacts there are "
                                                                        "replaced)" if clears_out else ")"))
    parser.add_argument("--no-live", action="store_true", help="no live channel view")
    add_no_plots_argument(parser)
    parser.add_argument("--scene", default=None, metavar="NAME",
                        help="objects in the board's world: one of the robot's scenes (default: the robot's); "
                             "summary.json reports how many toppled")
    parser.add_argument("--faults", default=None, metavar="SPEC",
                        help="emulated board: inject link faults both ways, e.g. drop=0.01,corrupt=0.01,dup=0.005,"
                             "reorder=0.005 (also truncate=P, delay=MS[±MS], cut=START+LEN)")
    parser.add_argument("--fault-seed", type=seed_arg, default=0, metavar="N",
                        help="seed of the fault injection (default 0; needs --faults)")
    parser.add_argument("--policy", default=None, metavar="FILE",
                        help="safety policy (TOML): allowed functions, tighter parameter bounds, motion budget")
    parser.add_argument("--firmware", choices=("python", "c", "qemu", "stm32f4"), default="python",
                        help="the emulated board's firmware: python (default), c (the C firmware built natively, "
                             "servos on a Feetech bus to the MuJoCo plant), qemu (the same C on an emulated "
                             "Cortex-M3, qemu-system-arm -M mps2-an385) or stm32f4 (its STM32F405 image on "
                             "qemu-system-arm -M netduinoplus2)")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress bars (rendering run.mp4); they are shown only on a terminal anyway")
    parser.add_argument("--foxglove", nargs="?", type=_port, const=8765, default=None, metavar="PORT",
                        help="live view: serve the run's channels (those of run.mcap) to Foxglove on "
                             "ws://127.0.0.1:PORT (default port 8765; off unless given)")
    parser.add_argument("--events", default=None, metavar="FILE",
                        help="scripted world events, one per line 'at SECONDS: text' (board time from the start); "
                             "the policy's [events] table says what each kind does (default: interrupt)")
    parser.add_argument("--push", action="append", default=[], type=push_arg, metavar="S:FX,FY,FZ[:DUR]",
                        help="emulated board only: push the robot's base at board time S with a force in newtons "
                             "(world frame) for DUR s (default 0.2); repeatable")
    add_mount_argument(parser)
    add_servo_bus_arguments(parser)
    parser.add_argument("--max-board-s", type=_bound, default=DEFAULT_MAX_BOARD_S, metavar="S",
                        help=f"stop a turn after S board seconds (default {DEFAULT_MAX_BOARD_S:g}; 0: no bound); "
                             "summary.json says so, exit status 1")
    parser.add_argument("--max-log-mb", type=_bound, default=DEFAULT_MAX_LOG_MB, metavar="MB",
                        help=f"stop when the frame logs reach MB megabytes (default {DEFAULT_MAX_LOG_MB:g}; 0: no bound)")


def _servo_bus(text: str) -> str:
    """``PORT[:BAUD]`` checked as the board checks it (firmware_sim.servobus.parse_bus_spec; the host imports
    nothing of the board): a port name, and a baud that is a whole number > 0 when given. The text after the
    last ``:`` is no baud when it holds a ``/``, when the whole text is a path that exists, or in a pyserial
    URL when it is the URL's own ``host:port``."""
    port, baud = _split_servo_bus(text)
    if not port:
        raise argparse.ArgumentTypeError(f"expected PORT[:BAUD] (e.g. /dev/ttyUSB0:1000000), got {text!r}")
    if baud and not baud.lstrip("-").isdigit():
        raise argparse.ArgumentTypeError(f"baud {baud!r} is not a number (expected PORT[:BAUD], e.g. "
                                         "/dev/ttyUSB0:1000000)")
    if baud and int(baud) <= 0:
        raise argparse.ArgumentTypeError(f"the baud rate must be > 0, got {baud} in {text!r}")
    return text


def _split_servo_bus(text: str) -> tuple[str, str]:
    """``PORT[:BAUD]`` -> ``(port, baud)`` (baud ``""`` when not given), as :func:`_servo_bus` reads it."""
    import os

    port, sep, baud = text.rpartition(":")
    if (not sep or "/" in baud or os.path.exists(text)
            or "://" in text and text.split("://", 1)[1].count(":") < 2):
        port, baud = text, ""
    return port, baud


def add_servo_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """``--servo-bus PORT[:BAUD] --bus-protocol sts|dxl2 --estop-torque hold|limp`` (run, chat, demo): the board the
    run starts drives the robot's real servos (docs/guides/hardware.md)."""
    parser.add_argument("--servo-bus", type=_servo_bus, default=None, metavar="PORT[:BAUD]",
                        help="the board this run starts drives the robot's REAL servos on this serial port (a USB "
                             "adapter, e.g. /dev/ttyUSB0); MuJoCo mirrors them. BAUD: default the robot's hardware.toml "
                             "(docs/guides/hardware.md)")
    parser.add_argument("--bus-protocol", choices=("sts", "dxl2"), default=None,
                        help="--servo-bus: sts (Feetech) or dxl2 (Dynamixel Protocol 2.0); default the robot's hardware.toml")
    parser.add_argument("--estop-torque", choices=("hold", "limp"), default=None,
                        help="--servo-bus: ESTOP holds position with torque on (hold, default) or switches torque off "
                             "(limp; back on at ESTOP_CLEAR from where the servos are)")


def servo_bus_problem(args: argparse.Namespace) -> str | None:
    """Why the ``--servo-bus`` flags cannot be used as given, or None."""
    bus = getattr(args, "servo_bus", None)
    if bus is None:
        if getattr(args, "bus_protocol", None) is not None or getattr(args, "estop_torque", None) is not None:
            return "--bus-protocol and --estop-torque need --servo-bus PORT"
        return None
    if getattr(args, "push", None):
        return "--push pushes a simulated robot; with --servo-bus the robot is real"
    if not (bool(getattr(args, "emulate_board", False)) or _implies_emulated(getattr(args, "link", "pty"))):
        return (f"--servo-bus is an option of the board this run starts, and {args.link} is a board you started: "
                "give that board the servo bus (`ghostshell board --link ... --servo-bus PORT`)")
    port = _split_servo_bus(bus)[0]
    if "://" not in port and os.name == "posix":  # a device path: there, and a device (not opened: that resets boards)
        try:
            mode = os.stat(port).st_mode
        except OSError as e:
            return (f"--servo-bus {bus}: there is no device {port!r} ({e.strerror or e}); give the servos' serial "
                    "adapter, e.g. /dev/ttyUSB0")
        if not stat.S_ISCHR(mode):
            return f"--servo-bus {bus}: {port!r} is not a serial device (a character device such as /dev/ttyUSB0)"
    return None


def servo_bus_of(args: argparse.Namespace) -> tuple[str, ...]:
    """The board arguments of the ``--servo-bus`` flags (``SessionOptions.servo_bus``; () without them)."""
    from host.run.options import servo_bus_args

    return servo_bus_args(getattr(args, "servo_bus", None), getattr(args, "bus_protocol", None),
                          getattr(args, "estop_torque", None))


def add_mount_argument(parser: argparse.ArgumentParser) -> None:
    """``--mount-mcp NAME=COMMAND...|NAME=URL`` (repeatable): an MCP server's tools as the module NAME."""
    from host.mounts.spec import parse_mount_arg

    parser.add_argument("--mount-mcp", action="append", default=[], type=parse_mount_arg,
                        metavar="NAME=COMMAND|NAME=URL",
                        help="mount an MCP server's tools as functions NAME.TOOL: a stdio server command "
                             "(e.g. weather='python weather.py') or a streamable HTTP URL; repeatable")


def mount_problem(args: argparse.Namespace, robot: Robot) -> str | None:
    """Why ``args.mount_mcp`` cannot be mounted on ``robot``'s shell, found without starting anything
    (a NAME given twice, a NAME that is already a module or channel of the robot's shell; a server
    command whose program is not found, a URL whose host is unknown or whose port refuses a
    connection: :func:`host.mounts.spec.launch_problem`), or None.

    The same check :func:`host.mounts.mcp_mount.mounted` makes once the shell is up, made here so that
    it refuses before the board starts or any file in ``--out`` is opened."""
    specs = tuple(getattr(args, "mount_mcp", ()) or ())
    if not specs:
        return None
    from host.mounts.spec import McpMountError, check_specs, launch_problem  # not mcp_mount: no MCP SDK here
    from host.runtime.binding import signature_registry

    try:
        check_specs(specs, signature_registry(robot, getattr(args, "vocabulary", None)))
    except McpMountError as e:
        return str(e)
    return next((why for why in map(launch_problem, specs) if why is not None), None)


def _number(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if v != v or v in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _positive(text: str) -> float:
    v = _number(text)
    if not v > 0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return v


def _port(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a port number 0..65535, got {text!r}") from None
    if not 0 <= v <= 65535:
        raise argparse.ArgumentTypeError(f"must be a port number 0..65535, got {text}")
    return v


def _non_negative(text: str) -> float:
    v = _number(text)
    if not v >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return v


def _bound(text: str) -> float | None:
    """A bound: a number > 0, or 0 for none (None)."""
    v = _non_negative(text)
    return v or None


#: the rate a real serial port opens at when ``--baud`` is not given
DEFAULT_PORT_BAUD = 115200


def line_rates(args: argparse.Namespace) -> tuple[int, int | None]:
    """``(baud, wire_baud)`` for a run's or a chat's session from ``--baud``: the rate a real port opens at,
    and the rate the emulated board models its wire at (its ``--baud``), set only when ``--baud`` was given
    and the command starts that board on a pty it creates and models (``--link pty``;
    :attr:`protocol.linkkinds.LinkKind.models_baud`): a real port's line has its own timing, and a CAN bus
    is not a serial line (:func:`check_run_args` refuses ``--baud`` with ``can:slcan:pty``)."""
    kind = link_kind(args.link)
    wire = args.baud if args.baud is not None and kind.board_creates and kind.models_baud else None
    return (args.baud or DEFAULT_PORT_BAUD), wire


def resolve_strict(args: argparse.Namespace) -> bool:
    """``--strict``/``--lenient`` if given; else strict for scripted replay, lenient for a real LLM."""
    if getattr(args, "strict", None) is not None:
        return bool(args.strict)
    return getattr(args, "llm", "scripted") == "scripted"


def check_run_args(args: argparse.Namespace) -> int | None:
    """The checks of ``run``/``demo`` flags that need no board: an exit status after one printed line, or None.

    Run before anything is printed, so a bad flag never follows the task banner. Sets ``args.robot_value``."""
    robot = getattr(args, "robot_value", None) or robot_from_args(args, args.command if "command" in args else "run")
    if isinstance(robot, int):
        return robot
    args.robot_value = robot
    why = servo_bus_problem(args)
    if why is not None:
        print_error(command_of(args), why)
        return USAGE_STATUS
    link = getattr(args, "link", None)
    if getattr(args, "baud", None) is not None and link is not None and link.implies_emulated_board \
            and not link_kind(link).models_baud:
        print_error(command_of(args), f"--baud: the emulated board on {link} does not model a serial line's rate "
                    f"(an SLCAN adapter's limit is the CAN bus's ?bitrate=); leave --baud out, or use --link pty")
        return USAGE_STATUS
    vocabulary = getattr(args, "vocabulary", None)
    if vocabulary is not None and vocabulary not in robot.interface.names:
        print_error(command_of(args), f"--vocabulary {vocabulary!r}: {robot.name} has {', '.join(robot.interface.names)}")
        return USAGE_STATUS
    scene = getattr(args, "scene", None)
    if scene is not None and scene not in robot.scenes:
        print_error(command_of(args), f"--scene {scene!r}: {robot.name} has {', '.join(robot.scenes)}")
        return USAGE_STATUS
    why = unreachable_link(args.link) or mount_problem(args, robot)
    foxglove = getattr(args, "foxglove", None)
    if why is None and foxglove:  # a taken port refuses before the board starts (0: any free port)
        taken = tcp_port_taken(foxglove)
        why = None if taken is None else f"--foxglove {foxglove}: {taken}"
    if why:
        print_error(command_of(args), f"{why}")
        return USAGE_STATUS
    if getattr(args, "policy", None):
        from host.run.events import EventFileError, EventPolicy
        from host.shell.policy import Policy, PolicyError

        try:
            from host.runtime.binding import function_params

            args.loaded_policy = Policy.load(args.policy, known=function_params(robot))
            args.event_policy = EventPolicy.load(args.policy)
        except (PolicyError, EventFileError) as e:
            print_error(command_of(args), f"{e}")
            return USAGE_STATUS
    if "skills" in args:  # the skill library (--skills FILE, else the default one): read now, refused with status 2
        from host.shell.skills import SkillError, SkillStore, skills_path

        try:
            args.skill_store = SkillStore(skills_path(args.skills))
        except SkillError as e:
            print_error(command_of(args), f"{e}")
            return USAGE_STATUS
    if getattr(args, "events", None):
        from host.run.events import EventFileError, parse_event_file

        try:
            args.scripted_events = tuple(parse_event_file(args.events))
        except EventFileError as e:
            print_error(command_of(args), f"--events {e}")
            return USAGE_STATUS
    if getattr(args, "push", None) and not (args.emulate_board or _implies_emulated(args.link)):
        print_error(command_of(args), f"--push acts in the emulated board a run starts, and {args.link} is a board you started: "
              "give that board --push, or let this run start one (--emulate-board)")
        return USAGE_STATUS
    faults, seed = getattr(args, "faults", None), getattr(args, "fault_seed", 0)
    if faults:
        from protocol.faults import FaultSpec, FaultSpecError
        from protocol.linkspec import LinkSpecError, parse_link_spec

        try:
            FaultSpec.parse(faults)
        except FaultSpecError as e:
            print_error(command_of(args), f"--faults: {e}")
            return USAGE_STATUS
        try:
            emulated = bool(args.emulate_board) or parse_link_spec(args.link).implies_emulated_board
        except LinkSpecError:
            emulated = bool(args.emulate_board)  # the link's own error comes when it is opened
        if not emulated:
            print_error(command_of(args), f"--faults is injected by the emulated board a run starts, and {args.link} is a board "
                  f"you started: give that board the faults (`ghostshell board --link ... --faults {faults}`), "
                  "or let this run start one (--emulate-board)")
            return USAGE_STATUS
    elif seed:
        print_error(command_of(args), "--fault-seed has no effect without a fault to inject (--faults SPEC; "
                    f"{faults!r} injects none)" if faults is not None else "--fault-seed has no effect without --faults")
        return USAGE_STATUS
    firmware = getattr(args, "firmware", "python")
    if firmware != "python":
        from protocol.linkspec import LinkSpecError, parse_link_spec

        try:
            spec = parse_link_spec(args.link)
        except LinkSpecError:
            spec = None
        if spec is not None and not (firmware in link_kind(spec).firmwares
                                     and (args.emulate_board or spec.implies_emulated_board)):
            served = " or a SocketCAN interface (can:socketcan:IF)" if firmware == "c" else ""
            print_error(command_of(args), f"--firmware {firmware} runs the emulated board this run starts on a serial link "
                  f"(--link pty){served}; {args.link} is not one")
            return USAGE_STATUS
        import shutil

        if firmware in ("qemu", "stm32f4") and shutil.which("qemu-system-arm") is None:  # as the board looks for it
            print_error(command_of(args), f"--firmware {firmware} runs the C firmware on qemu-system-arm, which is not "
                        "installed; install it with: apt-get install -y qemu-system-arm (.ci/setup does this as root)")
            return USAGE_STATUS
    emulate = bool(getattr(args, "emulate_board", False)) or args.link.implies_emulated_board
    why = preflight_link(args.link, emulated=emulate)  # last: it may open a CAN bus
    if why:
        print_error(command_of(args), f"{why}")
        return USAGE_STATUS
    args.run_args_checked = True
    return None


def _implies_emulated(link: object) -> bool:
    from protocol.linkspec import LinkSpecError, parse_link_spec

    try:
        return parse_link_spec(str(link)).implies_emulated_board
    except LinkSpecError:
        return False


def _push_text(p: tuple[float, tuple[float, float, float], float]) -> str:
    at, (fx, fy, fz), dur = p
    return f"{at!r}:{fx!r},{fy!r},{fz!r}:{dur!r}"


def run_with(args: argparse.Namespace, *, program: str | None, prompt: str | None, label: str,
             banner: str | None = None) -> int:
    """Build :class:`RunOptions` from ``args``, run, print where the artefacts are.

    ``banner`` (e.g. the task and its ground truth) is printed once the robot is up, just before
    the program streams: a run refused at the start (a port that cannot be opened) prints only
    its one error line."""
    import anyio

    from host.ghost import GhostError
    from host.link import LinkError
    from host.run.runner import RunOptions, ended_report, run_program
    from host.run.stops import Interrupted

    from host.shell.skills import SkillError, SkillStore, skills_path

    status = None if getattr(args, "run_args_checked", False) else check_run_args(args)
    if status is not None:
        return status
    skills = getattr(args, "skill_store", None)
    if skills is None:
        try:
            skills = SkillStore(skills_path(getattr(args, "skills", None)))
        except SkillError as e:  # a skill library that cannot be read is bad input
            print_error(command_of(args), f"{e}")
            return USAGE_STATUS
    policy = getattr(args, "loaded_policy", None)
    slug = label.replace(" ", "-")
    out = Path(args.out) if args.out else Path("runs") / slug
    why = None if args.out else out_dir_problem(out)  # a given --out was checked when it was parsed
    if why is not None:
        print_error(command_of(args), f"the run folder {out} {why}; give another with --out DIR")
        return USAGE_STATUS
    created = not out.exists()  # a run refused before it starts removes the folder it made
    try:  # set aside until the run has started: a start refused (a board, a servo bus, a CAN adapter) puts them back
        earlier = EarlierRun(out)
    except OSError as e:
        print_error(command_of(args), f"{out}/ holds an earlier run's artefacts that cannot be removed: {e}")
        return 1
    baud, wire_baud = line_rates(args)
    opts = RunOptions(
        program=program, prompt=prompt, llm=getattr(args, "llm", "scripted"), task_label=label,
        robot=str(args.robot_value.root), robots_dir=getattr(args, "robots_dir", None), vocabulary=args.vocabulary, mode=args.mode, strict=resolve_strict(args), lockstep=args.lockstep,
        link=args.link, emulate_board=args.emulate_board or None, baud=baud, wire_baud=wire_baud, out=out,
        tokens_per_s=args.tokens_per_s, seed=args.seed,
        llm_base_url=getattr(args, "base_url", None), llm_api_key=getattr(args, "api_key", None),
        interrupt_at=getattr(args, "interrupt_at", None), live=not args.no_live and sys.stdout.isatty(),
        scene=getattr(args, "scene", None),
        skills=skills,
        policy=policy, faults=getattr(args, "faults", None), fault_seed=getattr(args, "fault_seed", 0),
        max_board_s=args.max_board_s, max_log_mb=args.max_log_mb, handle_signals=True,
        firmware=getattr(args, "firmware", "python"), servo_bus=servo_bus_of(args),
        foxglove=getattr(args, "foxglove", None), plots=not getattr(args, "no_plots", False),
        mcp_mounts=tuple(getattr(args, "mount_mcp", ())),
        event_policy=getattr(args, "event_policy", None), events=getattr(args, "scripted_events", ()),
        pushes=tuple(_push_text(p) for p in getattr(args, "push", ())),
    )
    command = command_of(args)
    from host.run.link_health import board_warnings, timing_health_line

    started: list[bool] = []  # show_banner ran: the run began (an earlier run's files are then gone)

    def show_banner(*_: object) -> None:
        started.append(True)
        if earlier.names:  # the artefacts line then names only what this run wrote
            print_error(command, f"{out}/ held an earlier run's artefacts ({' '.join(earlier.names)}): removed; "
                        "this run writes its own", file=sys.stdout)
        earlier.discard()  # the run has started
        if banner is not None:
            print(banner, flush=True)

    try:
        report = anyio.run(run_program, opts, show_banner, backend="asyncio")
    except Interrupted as e:
        ended = ended_report(e)
        if ended is not None and not started and earlier.names:  # stopped while starting: the earlier run's
            ended = None  # files come back over the empty report (finally below)
        what = f"; {_counts(ended.summary.outcomes)}" if ended is not None else ""
        print_error(command, f"{e.how}{what}; "
              + (f"summary.json and timeline.json in {out}/" if ended is not None else
                 "nothing ran" + (f"; the earlier run's files in {out}/ are as they were" if earlier.names else "")))
        if ended is None:
            earlier.restore()
        if ended is None and created:
            remove_unused_out(out)
        return 130
    except (LinkError, GhostError, RuntimeError, OSError) as e:
        print_error(command_of(args), f"{e}")
        for warning in board_warnings(out / "board.stderr"):  # e.g. a --baud too slow for the handshake
            print(warning)
        kept = ended_report(e) is not None and (started or not earlier.names)
        if kept:  # a run the link ended still left its report (unless an earlier run's files come back over it)
            print(f"artefacts in {out}/: " + " ".join(n for n in ARTEFACTS if (out / n).exists()))
        status = link_exit_status(e)
        if ended_report(e) is None:  # refused before the run began: the earlier run's artefacts come back
            earlier.restore()
        if status == USAGE_STATUS and created and ended_report(e) is None:  # a link refused when opened (can:slcan:/dev/nonexist): no run folder
            remove_unused_out(out)
        return status
    finally:
        # any other end before the run started (a second Ctrl-C, an error of another kind): the earlier run's
        # files come back too (a no-op once show_banner discarded them, or after a restore above)
        earlier.restore()
    from host.run.artefacts import calls_table
    from host.run.link_health import link_health_line
    from host.run.realtime_health import realtime_behind_line

    s = report.summary
    if report.stop is not None:  # a signal or a bound stopped the run: one line says what and where
        rest = ("the turn had already ended" if report.rested is None else
                f"the robot went to its rest pose {args.robot_value.rest_pose!r}" if report.rested else
                "the robot could not be brought to its rest pose")
        print_error(command, f"{report.stop.message} at board time {report.board_t0 + s.duration_s:.2f} s "
              f"({s.duration_s:.2f} s into the run); "
              f"{_counts(s.outcomes)}; {rest}; artefacts in {out}/")
        timing = timing_health_line(s.extra)
        if timing is not None:
            print(timing)
        return report.stop.exit_status
    print(calls_table(report.calls, report.board_t0))  # board-measured, as timeline.json
    mounted = {m.name for m in opts.mcp_mounts}
    for o in report.result.observations:  # results of mounted tools are news; the robot's own are in the table
        if o.kind != "result" or (o.path or "").split(".", 1)[0].split("/")[-1] in mounted:
            print(o)
    seen = s.max_tilt_deg is not None and s.base_end is not None  # no SIM_STATE report: the pose is unknown
    print(f"\n{label}: {s.outcome}; {sum(s.outcomes.values())} calls {dict((k, v) for k, v in s.outcomes.items() if v)}; "
          f"board time {s.duration_s:.2f} s; {_first_action(s.first_action_latency_ms)}; "
          + (f"max tilt {s.max_tilt_deg:.1f} deg{'; FELL' if s.fell else ''}" if seen else "max tilt unknown"))
    print(f"base moved from {s.base_start} to {s.base_end} [x m, y m, yaw deg]" if seen else
          "base pose unknown: no SIM_STATE report reached the host (a line too slow for the board's reports drops them)")
    health = link_health_line(s.extra)
    if health is not None:
        print(health)
    timing = timing_health_line(s.extra)
    if timing is not None:
        print(timing)
    warnings = board_warnings(out / "board.stderr")  # e.g. a --baud too slow for the telemetry
    for warning in warnings:
        print(warning)
    behind = s.extra.get("realtime_behind")
    if isinstance(behind, dict) and not any("could not keep up" in w for w in warnings):  # the C boards say it themselves
        print(realtime_behind_line(behind))
    if s.extra.get("board_fault"):
        print_error(command_of(args), f"{s.extra['board_fault']}")
    scene = s.extra.get("scene") or {}
    if scene.get("objects"):
        print(f"scene {scene['name']}: {scene['toppled']} of {scene['objects']} toppled")
    if getattr(args, "video", False):
        render_into(out, quiet=getattr(args, "quiet", False), command=command_of(args))
    print(f"artefacts in {out}/: " + " ".join(n for n in (*ARTEFACTS, "run.mp4") if (out / n).exists()))
    if s.outcome in ("done", "interrupted"):
        return 0
    if not s.extra.get("board_fault"):  # (printed above) the reason on stderr too, for whoever reads only that
        failed = [c for c in report.calls if c.outcome == "failed"]
        first = next((f"{c.path}: {c.error}" for c in failed if c.error), None)
        why = (s.extra.get("error") or s.extra.get("link_error")
               or f"{len(failed)} of {len(report.calls)} calls failed" + (f", first {first}" if first else ""))
        print_error(command_of(args), f"the run ended {s.outcome}: {why}")
    return 1


ARTEFACTS = ("timeline.json", "timeline.png", "joints.png", "summary.json", "host_frames.jsonl", "board_frames.jsonl",
             "host_frames.log", "board_frames.log", "run.mcap")


def _counts(outcomes: dict[str, int]) -> str:
    """``"3 calls: 2 done, 1 interrupted"`` from summary.json's outcome counts."""
    n = sum(outcomes.values())
    parts = ", ".join(f"{v} {k}" for k, v in outcomes.items() if v)
    return f"{n} call{'s' if n != 1 else ''}" + (f": {parts}" if parts else "")


def _first_action(ms: float | None) -> str:
    return "no action" if ms is None else f"first action after {ms} ms"


def render_into(out: Path, quiet: bool = False, command: str = "run") -> bool:
    """Render ``out/run.mp4`` from the run's recorded state; print progress (a bar on a terminal) or why not."""
    import time

    from host.progress import bar
    from host.run.video import VideoError, render_video

    t = time.monotonic()
    try:
        with bar("rendering run.mp4", None, quiet=quiet, transient=True) as shown:
            path = render_video(out, progress=lambda done, total: shown.update(completed=done, total=total))
    except VideoError as e:
        print_error(command, f"no video: {e}")
        return False
    print(f"video: {path} (rendered in {time.monotonic() - t:.1f} s)")
    return True


def main(args: argparse.Namespace) -> int:
    program, prompt, banner = None, args.prompt, None
    if args.task is None and args.xml is None and args.xml_file is None and args.prompt is None:
        print_error("run", "one of the arguments --task --xml --xml-file --prompt is required")
        return 2
    from host.ghost import GhostError
    from host.ghost.factory import check_spec

    try:  # the spec's form before anything else: run_with clears --out and starts the board before the LLM is built
        args.llm = check_spec(args.llm)  # ' Scripted' as the runner reads it
    except GhostError as e:
        print_error("run", str(e))
        return 2
    if args.llm != "scripted" and args.prompt is None:  # the runner would send the LLM an empty instruction and ignore the tokens
        print_error("run", f"--llm {args.llm} answers --prompt TEXT; --task, --xml and --xml-file replay their "
                    "function tokens (leave --llm out)")
        return 2
    status = check_run_args(args)
    if status is not None:
        return status
    if args.task is not None:
        from robots.tasks import get_task

        robot = args.robot_value
        try:
            task = get_task(robot.tasks, args.task, robot.name)
        except ValueError as e:
            print_error("run", str(e))
            return 2
        program, label = task.ground_truth, f"task {task.id}"
        banner = f"task {task.id} ({task.category}): {task.instruction}\n  {task.ground_truth}"
    elif args.xml is not None:
        if not args.xml.strip():
            print_error("run", "--xml is empty: give function tokens, e.g. --xml '<head_act action=\"nod\"/>'")
            return 2
        program, label = args.xml, "program"
    elif args.xml_file is not None:
        try:
            program = read_text_input(args.xml_file, "--xml-file", what="function tokens")
        except InputError as e:
            print_error("run", str(e))
            return 2
        label = "stdin" if args.xml_file == STDIN else Path(args.xml_file).stem
    else:
        label = "prompt"
        if not args.prompt.strip():
            print_error("run", "--prompt is empty: give an instruction, e.g. --prompt 'Nod, then wave'")
            return 2
        if args.llm == "scripted":
            print_error("run", "--prompt needs a real LLM, e.g. --llm openai:gpt-4o-mini")
            return 2
        from host.ghost import make_ghost

        try:
            make_ghost(args.llm, base_url=args.base_url, api_key=args.api_key)  # bad spec/no key: before the board
        except GhostError as e:
            print_error("run", str(e))
            return 2
    if program is not None:
        from host.shell.limits import TurnLimits

        from host.runtime.binding import signature_registry
        from host.shell.precheck import refuse_program

        limits = TurnLimits()
        why = limits.refuse_reply(program)
        if why is None:  # every element's arguments too: a bad one late in the program must not move the robot first
            why = refuse_program(program, signature_registry(args.robot_value, getattr(args, "vocabulary", None)),
                                 limits.max_scope_timeout_s, strict=resolve_strict(args),
                                 mounts={m.name for m in args.mount_mcp})
        if why is not None:  # refused before the board starts, not cut minutes into the run
            source = f"--xml-file {args.xml_file}" if args.xml_file is not None else "the program"
            print_error("run", f"{source}: {why}; nothing was run")
            return 2
    return run_with(args, program=program, prompt=prompt, label=label, banner=banner)
