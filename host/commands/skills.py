"""``ghostshell skills list|show NAME|rm NAME``: the persistent skill library.

The library is the file given with ``--skills``, else ``$GHOSTSHELL_SKILLS``,
else ``skills.json`` in the user's data directory (see :func:`host.shell.skills.skills_path`).
Exit status: 0 done; 1 the library could not be written; 2 no such skill, or an unreadable library.
"""

from __future__ import annotations

import argparse
import sys

from host.commands.errors import print_error


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--skills", default=None, metavar="FILE", help="skill library file (else $GHOSTSHELL_SKILLS, "
                        "else the user data directory)")
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    for action, what in (("list", "list the saved skills"), ("show", "print a skill's program"),
                         ("rm", "delete a skill"), ("path", "print the library file's path")):
        p = sub.add_parser(action, help=what, description=what[0].upper() + what[1:] + ".")
        if action in ("show", "rm"):
            p.add_argument("name", metavar="NAME", help="the skill's name (ghostshell skills list)")


def main(args: argparse.Namespace) -> int:
    from host.shell.skills import SkillError, SkillStore, skills_path

    path = skills_path(args.skills)
    if args.action == "path":
        print(path)
        return 0
    try:
        store = SkillStore(path)
        if args.action == "list":
            if not len(store):
                print(f"no skills saved in {path}")
            for s in store.list():
                print(f"{s.name}\t{s.description or '-'}")
        elif args.action == "show":
            s = store.get(args.name)
            print(f"# {s.name}: {s.description or '(no description)'}\n{s.program}")
        elif args.action == "rm":
            store.delete(args.name)
            print(f"deleted skill {args.name!r} from {path}")
    except SkillError as e:  # an unknown skill, an unreadable library file: bad input
        print_error("skills", str(e))
        return 2
    except OSError as e:  # the library could not be written
        print_error("skills", str(e))
        return 1
    return 0
