"""``ghostshell vcan [--ifaces vcan0,vcan1] -- COMMAND ...``: run COMMAND with SocketCAN ``vcan`` interfaces up.

Where this kernel has the interfaces, or can create them (root and the ``vcan`` module), COMMAND runs
here, directly, after they are created (and they are deleted afterwards). Elsewhere (a kernel without
``vcan``, e.g. this machine's) it runs inside a throwaway User-Mode Linux guest (:mod:`host.tools.vcan.uml`):
the guest's root is this machine's root, so the working folder, the venv and every path outside
``/tmp`` are the same inside; the guest's ``/tmp`` is its own, but every ``/tmp`` path the command
names (an argument, an option's ``=VALUE``, or a path inside an argument such as a ``bash -c`` script)
is shared: the nearest folder of it that exists here is the same folder inside (``--keep DIR`` adds
one), and a path whose first folder below ``/tmp`` does not exist here yet (``--out /tmp/new/run``)
is copied out of the guest when the command ends (not when the guest is killed: Ctrl-C, timeout);
a path in the guest's own ``/run`` or ``/dev/shm`` gets a one-line warning; paths
built at run time (``mktemp``, ``$VAR``) are not seen: name them, or use ``--keep``. The kernel
modules the SocketCAN tests need (``sch_tbf`` for ``tc``) are loaded; output
streams to this terminal while COMMAND runs; the guest's files are removed afterwards (unless
``--run-dir``).

Exit status: COMMAND's own; 2 a usage error (no COMMAND, a bad interface name or option); 125 the
command could not be run (no SocketCAN here and no usable User-Mode Linux, or the guest failed to
boot; one line says why); 126 / 127 COMMAND is not executable / not found (as a shell); 130
interrupted (Ctrl-C or SIGTERM: the guest is killed, its files removed).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

from host.commands.errors import print_error
from host.commands.inputs import whole_number
from host.commands.outarg import out_dir

__all__ = ["configure", "main"]

USAGE, HARNESS_FAILED, NOT_EXECUTABLE, NOT_FOUND = 2, 125, 126, 127
#: Interface names: what ``ip link add`` takes (IFNAMSIZ 16 with the NUL; no '/', ':' or spaces).
_IFNAME = re.compile(r"[A-Za-z0-9_.-]{1,15}")


def _ifaces(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if not _IFNAME.fullmatch(n)]
    if bad or not names:
        raise argparse.ArgumentTypeError(
            f"{', '.join(map(repr, bad)) or repr(text)} is not a list of interface names: give names of 1-15 "
            "letters, digits, '_', '.' or '-' separated by commas, e.g. vcan0,vcan1")
    return names


def _modules(text: str) -> tuple[str, ...]:
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if not re.fullmatch(r"[A-Za-z0-9_-]+", n)]
    if bad:
        raise argparse.ArgumentTypeError(f"{', '.join(map(repr, bad))}: a kernel module name has only letters, digits, '_' and '-'")
    return names


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number of seconds, got {text!r}") from None
    if not 0 < v < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a number of seconds above 0, got {text}")
    return v


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ifaces", "--vcan", dest="ifaces", type=_ifaces, default=("vcan0", "vcan1"), metavar="LIST",
                        help="the vcan interfaces to bring up, comma-separated (default vcan0,vcan1)")
    parser.add_argument("--classic", action="store_true", help="classic CAN MTU 16 instead of CAN FD's 72")
    parser.add_argument("--txqueuelen", type=whole_number(1), default=None, metavar="N",
                        help="the interfaces' transmit queue length (a real can0 has 10)")
    parser.add_argument("--modules", type=_modules, default=("sch_tbf",), metavar="LIST",
                        help="further kernel modules to load, comma-separated (default sch_tbf: tc's token bucket, "
                             "which tests/socketcan uses); '' for none")
    parser.add_argument("--uml", action="store_true",
                        help="run in User-Mode Linux even where this kernel could create the interfaces")
    parser.add_argument("--timeout", type=_positive, default=3600.0, metavar="S",
                        help="kill COMMAND after S seconds (exit status 124; default 3600)")
    parser.add_argument("--keep", action="append", default=[], metavar="DIR",
                        help="User-Mode Linux: another folder under /tmp COMMAND needs (the working folder and "
                             "/tmp paths named in COMMAND, also inside a bash -c script, are shared without it)")
    parser.add_argument("--run-dir", type=out_dir, default=None, metavar="DIR",
                        help="User-Mode Linux: keep the guest's files (job, console, output) in DIR "
                             "(default: a temporary folder, removed at exit)")
    parser.add_argument("command", nargs=argparse.REMAINDER, metavar="-- COMMAND ...",
                        help="the command and its arguments")


#: an absolute path inside a command's argument (``bash -c "... > /tmp/x/cap.log"``, ``--out=/tmp/run``):
#: up to whitespace, a quote or a shell operator
_ABS_PATH = re.compile(r"""(?<![\w.~$-])/[^\s'"`;&|<>()$*?\[\]{}]*""")
#: the guest's own tmpfs folders besides /tmp: a file written there never reaches this machine
_GUEST_ONLY = ("/run", "/dev/shm")
TMP = Path("/tmp")


def _named_paths(argv: Sequence[str], cwd: Path) -> list[Path]:
    """Every path ``argv`` names, made absolute: a whole argument, an option's ``=VALUE``, and every
    absolute path inside an argument (a ``bash -c`` script's redirections and arguments)."""
    texts: list[str] = []
    for arg in argv:
        if "\n" not in arg:
            texts.append(arg.split("=", 1)[-1] if arg.startswith("-") else arg)
        texts += _ABS_PATH.findall(arg)
    found = []
    for text in texts:
        if not text or text == "/":
            continue
        p = Path(text) if os.path.isabs(text) else cwd / text
        try:
            found.append(Path(os.path.abspath(p)))  # no resolve yet: a symlink under /tmp is followed below
        except (OSError, ValueError):
            continue
    return found


def _tmp_paths(argv: Sequence[str], cwd: Path) -> tuple[list[Path], list[Path]]:
    """``(shared, copied_back)``: the host folders under ``/tmp`` a User-Mode Linux guest must see for the
    paths the command names there, and the paths directly under ``/tmp`` the command names that do not
    exist on this machine yet (the guest's ``/tmp`` is a private tmpfs; these are copied out of it when
    the command ends, :func:`host.tools.vcan.uml.run_in_uml` ``copy_back``).

    A named path's nearest folder that exists here is shared (``/tmp/x`` for ``--out /tmp/x/run/new``);
    when that is ``/tmp`` itself, the first folder below it (``/tmp/new`` for ``/tmp/new/run``) is
    copied back instead: sharing all of ``/tmp`` would share the host's temporary files with the
    guest's (a pytest inside would clean up the one outside)."""
    shared: list[Path] = []
    copied: list[Path] = []
    for p in _named_paths(argv, cwd):
        try:
            p = p.resolve()
            if p == TMP or TMP not in p.parents:
                continue
            folder = p if p.is_dir() else p.parent  # a file, or one the command will create
            while folder != TMP and not folder.is_dir():
                folder = folder.parent
        except (OSError, RuntimeError, ValueError):
            continue
        if folder != TMP:
            shared.append(folder)
        else:
            top = TMP / p.relative_to(TMP).parts[0]
            if not top.exists() and not top.is_symlink():
                copied.append(top)
    return sorted(set(shared)), sorted(set(copied))


def _guest_only_paths(argv: Sequence[str], cwd: Path) -> list[str]:
    """Paths the command names in the guest's own tmpfs folders (/run, /dev/shm): never shared."""
    return sorted({str(p) for p in _named_paths(argv, cwd)
                   if any(str(p) == g or str(p).startswith(g + "/") for g in _GUEST_ONLY)})


def _sink(stream: str, data: bytes) -> None:
    out = sys.stdout if stream == "stdout" else sys.stderr
    out.buffer.write(data)
    out.flush()


def _which(program: str, cwd: Path, path: str) -> str | None:
    if "/" in program:
        p = Path(program) if os.path.isabs(program) else cwd / program
        return str(p) if p.exists() else None
    return shutil.which(program, path=path)


def main(args: argparse.Namespace) -> int:
    from host.tools.vcan.native import native_plan, run_native
    from host.tools.vcan.uml import UmlError, default_env, run_in_uml, uml_unavailable_reason

    command = args.command[1:] if args.command[:1] == ["--"] else list(args.command)
    if not command:
        print_error("vcan", "no COMMAND given; put it after --, e.g. ghostshell vcan -- candump vcan0")
        return USAGE
    cwd = Path.cwd()
    env = default_env()
    exe = _which(command[0], cwd, env["PATH"])
    if exe is None:
        print_error("vcan", f"{command[0]}: command not found")
        return NOT_FOUND
    if not os.access(exe, os.X_OK) or os.path.isdir(exe):
        print_error("vcan", f"{command[0]}: not an executable file")
        return NOT_EXECUTABLE
    plan = None if args.uml else native_plan(args.ifaces)
    if plan is not None:
        try:
            return run_native(command, plan, fd=not args.classic, txqueuelen=args.txqueuelen, modules=args.modules,
                              cwd=cwd, env=env)
        except OSError as e:
            print_error("vcan", str(e))
            return HARNESS_FAILED
        except KeyboardInterrupt:
            print_error("vcan", "interrupted")
            return 130
    why = uml_unavailable_reason()
    if why is not None:
        print_error("vcan", f"this kernel cannot create {', '.join(args.ifaces)} and User-Mode Linux is unusable: "
              f"{why}")
        return HARNESS_FAILED
    temporary = args.run_dir is None
    run_dir = Path(tempfile.mkdtemp(prefix="uml_run_")) if temporary else Path(args.run_dir)
    shared, copied_back = _tmp_paths(command, cwd)
    keep = [Path(k) for k in args.keep] + shared
    unshared = _guest_only_paths(command, cwd)
    if unshared:
        print_error("vcan", f"warning: {', '.join(unshared)} {'is' if len(unshared) == 1 else 'are'} the User-Mode "
                    "Linux guest's own (its /run and /dev/shm are not this machine's): what COMMAND writes there "
                    "is lost; use a folder under /tmp or the working folder")
    try:
        result = run_in_uml(command, run_dir=run_dir, cwd=cwd, env=env, vcans=args.ifaces, fd=not args.classic,
                            txqueuelen=args.txqueuelen, keep=keep, copy_back=copied_back, extra_modules=args.modules,
                            timeout=args.timeout, on_output=_sink)
    except UmlError as e:
        first = str(e).partition("\n")[0]
        print_error("vcan", f"{first}" + (f" (details in {run_dir})" if not temporary else ""))
        return HARNESS_FAILED
    except KeyboardInterrupt:
        print_error("vcan", "interrupted; the User-Mode Linux guest was stopped")
        return 130
    finally:
        if temporary:
            shutil.rmtree(run_dir, ignore_errors=True)
    if result.returncode:
        kept = f"the guest's files are in {run_dir}" if not temporary else "--run-dir DIR keeps the guest's files"
        print_error("vcan", f"{command[0]} exited {result.returncode} after {result.seconds:.1f} s in User-Mode "
              f"Linux ({kept})")
    return result.returncode
