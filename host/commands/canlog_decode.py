"""``ghostshell log decode`` for CAN logs: every frame through the DBC (cantools), messages reassembled.

One line per frame: time, direction, identifier, the DBC message name and raw signal values (or
``UNKNOWN`` for a frame the DBC does not describe), then, indented, the protocol message the frame
completed (fixed layouts from their parts, bulk from ISO-TP) or the decode error. The message's
fields use the serial decoder's layout (:func:`protocol.framelog.format_fields`: ``mask=0x0fff``).

Exit status: 0 every frame decoded; 1 some frame is unknown or undecodable; 2 the file is not a
CAN log python-can reads (one line naming the first bad line of a candump ``.log``), or holds no
frame.
"""

from __future__ import annotations

from typing import IO

from protocol import framelog
from host.commands.errors import print_error

__all__ = ["decode_can_file"]


def decode_can_file(path: str, out: IO[str], err: IO[str], types: list[str] | None = None,
                    node: int | None = None, frames: bool = True) -> int:
    """Print a python-can log; exit code 0, 1 (unknown or undecodable frames, or a candump's last line cut
    off: the rest is printed) or 2 (not a CAN log, no frames)."""
    from host.link.canlog import candump_cut_line, candump_problem, is_candump

    if is_candump(path):
        problem = candump_problem(path)
        if problem is not None:
            print_error("log", str(problem), file=err)
            return 2
    from host.link.canlog import CanLogError, iter_can_log
    from protocol.can import CanItem
    from protocol.can.ids import split_id

    wanted = {t.upper() for t in types} if types else None
    n = kept = unknown = errors = 0
    nodes: set[int] = set()  # the node ids of the frames ?node= left out
    try:
        for e in iter_can_log(path):
            n += 1
            if node is not None:
                frame_node = split_id(e.frame.arbitration_id)[1]
                if frame_node not in (node, 0):
                    if len(nodes) < 128:
                        nodes.add(frame_node)
                    continue
            kept += 1
            if e.dbc_name is None:
                unknown += 1
            if frames and wanted is None:
                sig = framelog.format_fields(dict(e.signals))  # the DBC's signals, in the messages' layout
                name = e.dbc_name or "UNKNOWN"
                fd = " FD" if e.frame.is_fd else ""
                out.write(f"{e.t:17.6f} {e.direction} {e.frame.arbitration_id:03X}{fd} [{len(e.frame.data):2d}] "
                          f"{name:<22} {sig if e.dbc_name else e.frame.data.hex()}\n")
            for it in e.items:
                if isinstance(it, CanItem):
                    if wanted and it.msg_type.name not in wanted:
                        continue
                    text = framelog.format_fields(framelog.message_fields(it.msg))
                    via = "ISO-TP" if it.bulk else f"{len(it.frames)} frame(s)"
                    out.write(f"{'':17} {e.direction} #{it.seq:5d} {it.msg_type.name:<17} ({via}) {text}\n")
                else:
                    errors += 1
                    if wanted is None or "ERROR" in wanted:
                        out.write(f"{'':17} {e.direction} ERROR {it.kind.value}: {it.detail}\n")
    except BrokenPipeError:  # piped into head
        return 0
    except CanLogError as ex:  # python-can's readers: a damaged .asc/.blf (the message names the file)
        print_error("log", str(ex), file=err)
        return 2
    except (OSError, ValueError, EOFError) as ex:
        print_error("log", f"cannot read {path} as a CAN log ({type(ex).__name__}: {ex})", file=err)
        return 2
    except Exception as ex:  # noqa: BLE001 - python-can's BLF reader raises struct.error and others
        print_error("log", f"python-can cannot read {path} as a CAN log ({type(ex).__name__}: {ex})", file=err)
        return 2
    if not n:
        print_error("log", f"{path} holds no CAN frames: nothing to decode", file=err)
        return 2
    if not kept:  # ?node= matched nothing: it printed nothing and said nothing
        print_error("log", f"?node={node}: none of the {n} frame(s) of {path} is node {node}'s; it holds node(s) "
                    f"{', '.join(map(str, sorted(nodes)))}", file=err)
        return 2
    cut = candump_cut_line(path) if is_candump(path) else None
    if cut is not None:  # as a .jsonl's bad line or a cut run.mcap: the rest printed, exit status 1
        print_error("log", f"{path}:{cut} is cut off (no newline at its end: the logger stopped while writing it); "
                    f"skipped, {n} whole frame(s) read", file=err)
    if unknown or errors:
        print_error("log", f"{n} frame(s), {unknown} not in the DBC, {errors} decode error(s)", file=err)
        return 1
    return 1 if cut is not None else 0
