"""``ghostshell log decode FILE``: print a frame log readably: serial JSON Lines (:mod:`protocol.framelog`),
a CAN log in a python-can format (``.log`` candump, ``.asc``, ``.blf``: through the DBC, see
:mod:`host.commands.canlog_decode`), or a run's ``run.mcap`` (:mod:`host.run.mcap_read`: one line per
message, ``board-time topic {decoded fields}``, then a per-topic count on stderr).

Big MCAP messages are summarised, not printed: one whose payload is over :data:`SUMMARISE_OVER_BYTES`
(not even turned into a dict) or whose line would be over :data:`MAX_LINE_CHARS` prints
``board-time topic <schema: N B; entities 7, models 13, ...>`` (the element count of each repeated
field). A robot's ``/scene`` with meshes is megabytes: printed whole it was a line of tens of MB and
took seconds. Bytes fields (a photo's PNG, a mesh's STL) print as ``<N B>``.

Exit status: 0 every record decoded; 1 some records could not be decoded (each named with its line;
the rest are printed); 2 the file is missing, empty, not a frame log at all, or ``--type`` names no
message type (the valid names are listed).
"""

from __future__ import annotations

import argparse
import os
import sys
from typing import IO

from host.bounded_read import MAX_LOG_LINE, special_file_problem
from host.commands.errors import print_error
from host.commands.linkarg import add_link_argument
from protocol.linkkinds import link_kind

__all__ = ["MAX_LINE_CHARS", "SUMMARISE_OVER_BYTES", "configure", "decode_file", "decode_mcap_file", "main"]

#: an MCAP message whose encoded payload is over this many bytes is summarised without decoding it to text
SUMMARISE_OVER_BYTES = 1024 * 1024
#: a decoded MCAP message whose line would be longer than this (characters) is summarised instead
MAX_LINE_CHARS = 16 * 1024


def configure(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    decode_help = "print every record of a frame log, one line each"
    p = sub.add_parser("decode", help=decode_help,
                       description=decode_help[0].upper() + decode_help[1:] + " (time, direction, message type "
                       "and its fields): a serial JSON Lines log, a CAN log (candump .log, .asc, .blf; through the "
                       "robot's DBC) or a run's run.mcap (then a count per topic on stderr). Exit status 1 when "
                       "some records could not be decoded (each is named; the rest are printed).")
    p.add_argument("file", metavar="FILE", help="a log written with --log (by the board or the host): .jsonl serial; "
                   ".log/.asc/.blf CAN; or a run's run.mcap")
    p.add_argument("--type", action="append", default=None, metavar="NAME",
                   help="only records of this message type (repeatable), e.g. --type TELEMETRY; for an MCAP a "
                        "topic or schema, e.g. --type /joint_states")
    add_link_argument(p, default=None, required=False, help="the link the log was recorded on (default: by the file's suffix; "
                      ".jsonl = serial JSON Lines); for CAN logs ?node=N picks the board")


#: ``--type`` values: the protocol's message types and ERROR (a record that did not decode)
def type_names() -> list[str]:
    from protocol.messages import MsgType

    return [t.name for t in MsgType] + ["ERROR"]


def decode_file(path: str, out: IO[str] | None = None, err: IO[str] | None = None, types: list[str] | None = None) -> int:
    """Print ``path``'s records; bad lines are reported with their number and skipped. Returns an exit code."""
    out = sys.stdout if out is None else out  # resolved per call: a default bound at import would pin
    err = sys.stderr if err is None else err  # the stream of whoever imported first (pytest's capture, a redirect)
    from protocol.framelog import FrameLogError, format_record, from_line

    problem = special_file_problem(path)
    if problem is not None:
        print_error("log", problem, file=err)
        return 2
    wanted = {t.upper() for t in types} if types else None
    try:
        f = open(path, encoding="utf-8")
    except OSError as e:
        print_error("log", f"cannot read {path}: {e.strerror or e}", file=err)
        return 2
    bad = good = 0
    held: list[str] = []  # bad lines before the first good record: said only if the file is a frame log at all
    with f:
        for lineno, line in enumerate(iter(lambda: f.readline(MAX_LOG_LINE + 1), ""), 1):
            if len(line) > MAX_LOG_LINE:  # no record is this long: not a frame log (and not read further)
                print_error("log", f"{path}:{lineno} is longer than {MAX_LOG_LINE} characters: not a frame log; "
                            "give a file written with --log", file=err)
                return 2
            if not line.strip():
                continue
            try:
                rec = from_line(line)
            except (FrameLogError, UnicodeDecodeError) as e:
                bad += 1
                note = f"{path}:{lineno}: not a frame-log record: {e}"
                if good:
                    print(note, file=err)
                elif len(held) < 20:
                    held.append(note)
                continue
            if not good:
                for note in held:
                    print(note, file=err)
            good += 1
            if wanted and rec.get("type", "ERROR" if "error" in rec else "") not in wanted:
                continue
            out.write(format_record(rec) + "\n")
    if bad and not good:
        first = held[0].replace(": not a frame-log record", "") if held else path
        print_error("log", f"{path} is not a frame log ({first}); give a file written with --log: .jsonl "
              "for a serial link, .log/.asc/.blf for CAN (a CAN capture under another name: --link can:…)", file=err)
        return 2
    if bad:
        print_error("log", f"{bad} bad line(s) skipped, {good} record(s) decoded", file=err)
        return 1
    if not good:
        print_error("log", f"{path} holds no records: nothing to decode", file=err)
        return 2
    return 0


def decode_mcap_file(path: str, out: IO[str] | None = None, err: IO[str] | None = None, types: list[str] | None = None) -> int:
    """Print a run.mcap's messages in board-time order (a cut file: in file order, up to its last chunk)."""
    out = sys.stdout if out is None else out  # resolved per call: a default bound at import would pin
    err = sys.stderr if err is None else err  # the stream of whoever imported first (pytest's capture, a redirect)
    import json

    from host.run.mcap_read import McapReadError, McapRun, MessageSummary

    try:
        run = McapRun(path)
    except McapReadError as e:
        print_error("log", str(e), file=err)
        return 2
    wanted = {t.lower() for t in types} if types else None
    counts: dict[str, int] = {}
    for m in run.messages(summarise_over=SUMMARISE_OVER_BYTES):
        if wanted and m.topic.lower() not in wanted and m.schema.lower() not in wanted:
            continue
        counts[m.topic] = counts.get(m.topic, 0) + 1
        if isinstance(m.value, MessageSummary):
            text = str(m.value)
        else:
            text = json.dumps(_shorten(m.value), ensure_ascii=False, separators=(",", ":"), default=str)
            if len(text) > MAX_LINE_CHARS:
                text = str(MessageSummary(m.schema, m.size, _list_counts(m.value, {})))
        out.write(f"{m.log_time_ns / 1e9:12.6f} {m.topic:<15} {text}\n")
    print_error("log", (", ".join(f"{t} {n}" for t, n in counts.items()) or "no messages"), file=err)
    if run.truncated:
        print_error("log", str(run.truncated), file=err)
        return 1
    return 0


def _shorten(value):
    """Image bytes (base64 in the decoded message) as their size, so a photo is one short line."""
    if isinstance(value, dict):
        return {k: (f"<{len(v) * 3 // 4} B>" if k == "data" and isinstance(v, str) and len(v) > 64 else _shorten(v))
                for k, v in value.items()}
    if isinstance(value, list):
        return [_shorten(v) for v in value]
    return value


def _list_counts(value: object, counts: dict[str, int]) -> dict[str, int]:
    """Element counts of every list in a decoded message, by its field name (summed)."""
    if isinstance(value, dict):
        for k, v in value.items():
            if isinstance(v, list):
                counts[k] = counts.get(k, 0) + len(v)
            _list_counts(v, counts)
    elif isinstance(value, list):
        for v in value:
            if isinstance(v, (dict, list)):
                _list_counts(v, counts)
    return counts


def main(args: argparse.Namespace) -> int:
    from host.link.canlog import CAN_LOG_SUFFIXES

    problem = special_file_problem(args.file)  # /dev/zero, a FIFO: endless or blocking, never a log
    if problem is not None:
        print_error("log", problem)
        return 2
    if args.file.lower().endswith(".mcap"):
        if args.link is not None:  # a run.mcap holds one run with one board: nothing to pick
            print_error("log", "note: --link is not used for an MCAP file (a run.mcap holds one board's run)")
        try:
            return decode_mcap_file(args.file, types=args.type)
        except BrokenPipeError:
            return 0
    if args.type:
        known = type_names()
        unknown = [t for t in args.type if t.upper() not in known]
        if unknown:
            print_error("log", f"--type {', '.join(unknown)}: no such message type; the types are "
                  f"{', '.join(known)}")
            return 2

    link_is_can = args.link is not None and link_kind(args.link).wire == "can"
    file_is_can = args.file.lower().endswith(CAN_LOG_SUFFIXES)
    file_is_serial = args.file.lower().endswith(".jsonl")
    # a --link whose log format the file's suffix contradicts (a file with another suffix, or none, is
    # read in the link's format: candump text on CAN); a missing file or a folder gets the readers' line
    if args.link is not None and (file_is_serial if link_is_can else file_is_can) and os.path.isfile(args.file):
        wants = f"a CAN log ({', '.join(CAN_LOG_SUFFIXES)})" if link_is_can else "a serial JSON Lines log (.jsonl)"
        print_error("log", f"--link {args.link} records {wants}, and {args.file} is "
                    f"{'a serial JSON Lines log' if link_is_can else 'a CAN log'} by its suffix; "
                    "without --link the suffix picks the format")
        return 2
    is_can = link_is_can or (args.link is None and file_is_can)
    try:
        if is_can:
            from host.commands.canlog_decode import decode_can_file

            node = args.link.node if link_is_can else None
            return decode_can_file(args.file, sys.stdout, sys.stderr, types=args.type, node=node)
        return decode_file(args.file, types=args.type)
    except BrokenPipeError:  # e.g. piped into head
        return 0
    except UnicodeDecodeError as e:
        print_error("log", f"{args.file} is not a text frame log: {e}")
        return 2
