"""``ghostshell robots new|check|list|show|path|calibrate``: make, list, inspect and calibrate robot packages.

* ``new NAME --mjcf FILE`` writes a robot package generated from one MJCF (rules:
  :mod:`robots.generate`) into the user robot folder (``--robots-dir``, else the first folder of
  ``$GHOSTSHELL_ROBOTS``, else platformdirs' user data folder; :func:`robots.registry.new_robots_dir`).
  An existing folder of that name is refused unless ``--force``, and so is a name that would shadow
  another robot on the search path (e.g. a built-in one).
  It prints its notes (``note: ...`` on stderr: skipped actuators, servo ranges an actuator ``ctrlrange``
  changed, ...) once, and ends with a ``try:`` command that moves one joint visibly.
* ``check NAME``: the loader's checks, always against the MJCF (no recorded pass), and the package's notes
  (:func:`robots.loader.mjcf_notes`). Loading a robot for any other command prints only a note on a
  problem (a servo table that keeps the joint range where the ctrlrange is narrower), and only when the
  load checks the MJCF, i.e. once after the package changed, not on every command.
* ``list``: every robot on the search path (:mod:`robots.registry`): name, servo count, built-in or
  user, folder, and a note when one shadows another; a broken package is listed with its error line.
* ``show NAME``: :meth:`robots.description.Robot.describe` plus the functions each vocabulary exposes.
* ``path [NAME]``: the folder ``new`` writes into, or robot NAME's folder.
* ``calibrate NAME --servo-bus PORT[:BAUD]``: record each real servo's offset, direction and range into the
  package's ``calibration.toml`` (:mod:`host.commands.calibrate`; docs/guides/calibration.md).

Bad input (an MJCF that makes no robot, a broken package, a name that finds nothing) is one line on
stderr naming what and where (file:line where there is one) and exit status 2.
"""

from __future__ import annotations

import argparse
import inspect
import math
import sys
from typing import Any, get_args, get_origin

from host.commands.errors import print_error
from robots.description import Robot, RobotDataError
from robots.registry import robots_dir_arg

__all__ = ["configure", "main"]

USAGE_STATUS = 2


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    dir_help = "a folder of robots searched first (and where `new` writes)"
    new = sub.add_parser("new", help="generate a robot package from one MJCF file (no code)",
                         description="Generate a robot package from one MJCF: servos from its position actuators, "
                                     "poses zero and home, the generic functions pose and joint_move.")
    new.add_argument("name", metavar="NAME", help="the robot's name, [a-z][a-z0-9_]*")
    new.add_argument("--mjcf", required=True, metavar="FILE", help="the MuJoCo model (MJCF XML)")
    new.add_argument("--robots-dir", default=None, metavar="DIR", help=dir_help)
    new.add_argument("--force", action="store_true", help="replace an existing robot folder / shadow another robot")
    new.add_argument("--max-speed-dps", type=float, default=None, metavar="DPS",
                     help="every servo's speed limit in deg/s (default: robots.generate.DEFAULT_MAX_SPEED_DPS)")
    new.add_argument("--title", default=None, metavar="TEXT", help="a title for people (default: the MJCF's model name)")
    lst = _action(sub, "list", "list built-in and user robots with their servo counts")
    lst.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg, help=dir_help)
    show = _action(sub, "show", "describe a robot and the functions it exposes")
    show.add_argument("name", metavar="NAME", help="a robot name or a robot folder")
    show.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg, help=dir_help)
    check = sub.add_parser("check", help="check a robot package against its MJCF again and print its notes",
                           description="Check robot NAME as every load does, but always against its MJCF (no "
                                       "recorded pass), and print its notes (servo ranges an actuator ctrlrange "
                                       "changed); exit 2 with one line when it is broken.")
    check.add_argument("name", metavar="NAME", help="a robot name or a robot folder")
    check.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg, help=dir_help)
    path = _action(sub, "path", "print the user robot folder (where `new` writes), or robot NAME's folder")
    path.add_argument("name", nargs="?", default=None, metavar="NAME", help="a robot name (default: none, the user folder)")
    path.add_argument("--robots-dir", default=None, metavar="DIR", type=robots_dir_arg, help=dir_help)
    from host.commands import calibrate  # ``robots calibrate``: its own module (the vendor SDKs load when it runs)
    calibrate.configure(sub.add_parser("calibrate", help=calibrate.HELP, description=calibrate.DESCRIPTION))


def _action(sub: Any, name: str, what: str) -> argparse.ArgumentParser:
    """``robots NAME``'s parser: ``what`` is its line in ``robots --help`` and, as a sentence, its description."""
    parser: argparse.ArgumentParser = sub.add_parser(name, help=what, description=what[0].upper() + what[1:] + ".")
    return parser


def _fail(message: str) -> int:
    print_error("robots", str(message))
    return USAGE_STATUS


# --- new ------------------------------------------------------------------------------------------


def _new(args: argparse.Namespace) -> int:
    from robots.generate import DEFAULT_MAX_SPEED_DPS, generate_package, install_package
    from robots.registry import find_robot, new_robots_dir

    target = new_robots_dir(args.robots_dir)
    folder = target / args.name
    speed = DEFAULT_MAX_SPEED_DPS if args.max_speed_dps is None else args.max_speed_dps
    try:
        pkg = generate_package(args.name, args.mjcf, max_speed_dps=speed, title=args.title)
        try:
            other, builtin = find_robot(args.name, args.robots_dir)
        except RobotDataError:
            other = None
        if other is not None and other != folder.resolve() and not args.force:
            kind = "the built-in robot" if builtin else "the robot"
            return _fail(f"{folder}: a robot {args.name!r} there would shadow {kind} in {other}; choose another name "
                         "or pass --force")
        written = install_package(pkg, target, force=args.force)
    except RobotDataError as e:
        return _fail(str(e))
    for note in pkg.notes:
        print(f"note: {note}", file=sys.stderr)
    kinds = ", ".join(f"{s.id}:{s.joint}" + (" (slide)" if s.kind == "slide" else "") for s in pkg.servos)
    print(f"robot {pkg.name}: {len(pkg.servos)} servos ({kinds}), poses {', '.join(pkg.poses)}, "
          f"{'floating' if pkg.floating else 'fixed'} base, camera {pkg.camera or 'none'}")
    print(f"written to {written} ({', '.join(sorted([*pkg.texts, *pkg.copies]))})")
    print(try_command(pkg, args.robots_dir))
    return 0


def try_command(pkg: Any, robots_dir: str | None = None) -> str:
    """The ``try:`` line ``new`` ends with: a run that visibly moves one joint from the start pose (``home``):
    the joint whose move sweeps the most (:attr:`robots.generate.GeneratedServo.sweep_m`: not a wrist roll
    that turns a link about its own axis), half way from home to its farther limit."""
    import shlex

    home = dict(zip((s.joint for s in pkg.servos), pkg.poses["home"]))
    best = max(pkg.servos, key=lambda s: (s.sweep_m, s.max_deg - s.min_deg))
    h = home[best.joint]
    far = best.max_deg if best.max_deg - h >= h - best.min_deg else best.min_deg
    deg = min(max(round(h + (far - h) / 2), math.ceil(best.min_deg)), math.floor(best.max_deg))
    where = f" --robots-dir {shlex.quote(str(robots_dir))}" if robots_dir else ""
    xml = f'<joint_move joint="{best.joint}" deg="{deg}" duration="1"/>'
    return f"try: ghostshell run --robot {pkg.name}{where} --xml {shlex.quote(xml)}"


# --- check ----------------------------------------------------------------------------------------


def _check(args: argparse.Namespace) -> int:
    from robots.loader import load_robot_dir, mjcf_notes
    from robots.registry import find_robot

    try:
        folder, builtin = find_robot(args.name, args.robots_dir)
        robot = load_robot_dir(folder, builtin=builtin, fresh=True, show_notes=False)  # mjcf_notes says them all
        notes = mjcf_notes(robot)
    except RobotDataError as e:
        return _fail(str(e))
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    print(f"robot {robot.name}: ok ({robot.servo_count} servos, poses {', '.join(robot.poses)}; {robot.mjcf} checked)")
    return 0


# --- list -----------------------------------------------------------------------------------------


def _list(args: argparse.Namespace) -> int:
    from robots.loader import load_robot_dir
    from robots.registry import DEFAULT_ROBOT, list_robots, search_path

    entries = list_robots(args.robots_dir)
    if not entries:
        print("no robots found (searched " + ", ".join(str(f) for f, _ in search_path(args.robots_dir)) + ")")
        return 0
    rows = []
    for e in entries:
        notes = []
        try:
            robot = load_robot_dir(e.folder, builtin=e.builtin)
            servos = str(robot.servo_count)
        except RobotDataError as err:
            servos, notes = "-", [f"broken: {err}"]
        if e.shadowed_by is not None:
            notes.append(f"hidden by {e.shadowed_by}")
        else:
            hidden = [o for o in entries if o.name == e.name and o.shadowed_by is not None]
            if hidden:
                notes.append("shadows " + ", ".join(str(o.folder) for o in hidden))
            if e.builtin and e.name == DEFAULT_ROBOT:
                notes.append("default")
        rows.append((e.name, servos, "built-in" if e.builtin else "user", str(e.folder), "; ".join(notes)))
    head = ("NAME", "SERVOS", "WHERE", "FOLDER", "NOTE")
    widths = [max(len(r[i]) for r in (head, *rows)) for i in range(4)]
    for r in (head, *rows):
        print("  ".join(c.ljust(w) for c, w in zip(r[:4], widths)) + ("  " + r[4] if r[4] else ""))
    return 0


# --- show -----------------------------------------------------------------------------------------


def _type_text(ann: Any) -> str:
    """A parameter's type for one line: ``zero|home``, ``float 0..120``, ``str``."""
    from typing import Annotated, Literal

    if get_origin(ann) is Annotated:
        base, *meta = get_args(ann)
        bounds = []
        for m in meta:
            lo = getattr(m, "ge", None)
            lo = getattr(m, "gt", None) if lo is None else lo
            hi = getattr(m, "le", None)
            hi = getattr(m, "lt", None) if hi is None else hi
            if lo is not None or hi is not None:
                bounds.append(f"{'' if lo is None else f'{lo:g}'}..{'' if hi is None else f'{hi:g}'}")
        return " ".join([_type_text(base), *bounds])
    if get_origin(ann) is Literal:
        return "|".join(str(a) for a in get_args(ann))
    return getattr(ann, "__name__", str(ann))


def _signature(fn: Any) -> str:
    import typing

    hints = typing.get_type_hints(fn, include_extras=True)
    parts = []
    for p in list(inspect.signature(fn).parameters.values())[1:]:  # without self
        s = f"{p.name}: {_type_text(hints.get(p.name, Any))}"
        if p.default is not inspect.Parameter.empty:
            s += f" = {p.default!r}"
        parts.append(s)
    return f"{fn.__name__}({', '.join(parts)})"


def _functions(robot: Robot) -> list[str]:
    iface = robot.interface
    lines = []
    for vocab in iface.names:
        lines.append(f"  functions ({vocab} vocabulary{', the default' if vocab == iface.default else ''}):")
        for name, (fn, info) in iface.stubs(vocab).items():
            doc = " ".join((fn.__doc__ or "").split()).split(". ")[0].rstrip(".")
            lines.append(f"    {_signature(fn)}  [channel {info.channel}]" + (f"  {doc}" if doc else ""))
    for name, why in iface.left_out.items():
        lines.append(f"  left out: {name} ({why})")
    return lines


def _show(args: argparse.Namespace) -> int:
    from robots.registry import load_robot

    try:
        robot = load_robot(args.name, args.robots_dir)
        lines = [robot.describe(), *_functions(robot)]
    except RobotDataError as e:
        return _fail(str(e))
    print("\n".join(lines))
    return 0


# --- path -----------------------------------------------------------------------------------------


def _path(args: argparse.Namespace) -> int:
    from robots.registry import find_robot, new_robots_dir

    if args.name is None:
        print(new_robots_dir(args.robots_dir))
        return 0
    try:
        folder, _builtin = find_robot(args.name, args.robots_dir)
    except RobotDataError as e:
        return _fail(str(e))
    print(folder)
    return 0


def main(args: argparse.Namespace) -> int:
    from host.commands import calibrate

    return {"new": _new, "check": _check, "list": _list, "show": _show, "path": _path,
            "calibrate": calibrate.main}[args.action](args)
