"""Read a user-given file or standard input whole, but never more than a cap.

Every place the host reads a file the user named (``run --xml-file``, ``chat --turns``, a policy, a
skill library, an event file, ...) goes through :func:`read_capped`, so ``/dev/zero``, an endless
pipe (``yes ... |``) or a huge file is refused after ``cap + 1`` bytes instead of growing memory
without bound. A named FIFO with no writer is opened non-blocking, so it reads as empty instead of
hanging. The caps, in bytes, are the ``MAX_*`` constants below (one per kind of input).
"""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path
from typing import BinaryIO

__all__ = ["MAX_EVENT_FILE", "MAX_LINE", "MAX_LOG_LINE", "MAX_POLICY", "MAX_PROGRAM", "MAX_SKILLS", "MAX_TEXT", "InputTooLarge",
           "read_capped", "read_capped_stream", "size_text", "special_file_problem",
           "stdin_bytes"]

#: bytes of a text input a command reads whole: a program of function tokens (``run --xml-file``,
#: ``dsbc @FILE``; the shell refuses programs over 5 000 calls, well under a megabyte), ``chat --turns``
#: / ``--replies``, ``eval --replies``
MAX_TEXT = 4 * 1024 * 1024
MAX_PROGRAM = MAX_TEXT
#: bytes of a TOML policy file (``--policy``)
MAX_POLICY = 1024 * 1024
#: bytes of a scripted event file (at most 10 000 events)
MAX_EVENT_FILE = 2 * 1024 * 1024
#: bytes of a skill library (JSON of saved programs)
MAX_SKILLS = 32 * 1024 * 1024
#: bytes of one line typed to ``chat`` on standard input
MAX_LINE = 64 * 1024
#: characters of one line of a serial frame log (.jsonl): a record of one frame (at most 512 bytes on
#: the wire) is a few KiB; a longer line is no record (``/dev/zero``, a binary file)
MAX_LOG_LINE = 1024 * 1024


class InputTooLarge(ValueError):
    """The input holds more than the cap; the message says the cap."""


def size_text(n: int) -> str:
    """``n`` bytes as a short text: ``4 MiB``, ``64 KiB``, ``100 bytes``."""
    for unit, size in (("MiB", 1024 * 1024), ("KiB", 1024)):
        if n >= size and n % size == 0:
            return f"{n // size} {unit}"
    return f"{n} bytes"


def _too_large(cap: int) -> InputTooLarge:
    return InputTooLarge(f"it holds more than {size_text(cap)}, the most this input may hold")


def read_capped_stream(stream: BinaryIO, cap: int) -> bytes:
    """At most ``cap`` bytes of ``stream`` to its end; :class:`InputTooLarge` (after reading ``cap + 1``
    bytes, never more) when it holds more."""
    data = stream.read(cap + 1)
    if len(data) > cap:
        raise _too_large(cap)
    return bytes(data)


def read_capped(path: str | Path, cap: int) -> bytes:
    """The bytes of ``path``, at most ``cap``; :class:`InputTooLarge` when it holds more (``/dev/zero``
    is refused after ``cap + 1`` bytes), :class:`IsADirectoryError` for a folder, :class:`OSError`
    when it cannot be opened. A FIFO is opened non-blocking (no writer: it reads as empty, no hang)."""
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        st = os.fstat(fd)
        if stat.S_ISDIR(st.st_mode):
            raise IsADirectoryError(21, "Is a directory", str(path))
        if stat.S_ISREG(st.st_mode) and st.st_size > cap:
            raise _too_large(cap)
        if sys.platform != "win32":
            import fcntl

            # blocking reads from here on (a pipe with a writer waits for its data, as stdin does)
            fcntl.fcntl(fd, fcntl.F_SETFL, fcntl.fcntl(fd, fcntl.F_GETFL) & ~os.O_NONBLOCK)
        chunks: list[bytes] = []
        got = 0
        while got <= cap:
            chunk = os.read(fd, min(1 << 20, cap + 1 - got))
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
        if got > cap:
            raise _too_large(cap)
        return b"".join(chunks)
    finally:
        os.close(fd)


def stdin_bytes(cap: int) -> bytes:
    """At most ``cap`` bytes of standard input to its end (see :func:`read_capped_stream`)."""
    if sys.stdin is None:
        raise OSError("there is no standard input to read")
    if hasattr(sys.stdin, "buffer"):
        return read_capped_stream(sys.stdin.buffer, cap)
    text = sys.stdin.read(cap + 1)
    data = text.encode("utf-8")
    if len(text) > cap or len(data) > cap:
        raise _too_large(cap)
    return data


def special_file_problem(path: str | Path) -> str | None:
    """Why ``path`` cannot be a log file to read (a device such as ``/dev/zero``, a FIFO, a socket:
    endless or blocking), or None (a regular file, a folder, or a path that is not there: the readers
    say those)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return None
    kind = ("a FIFO" if stat.S_ISFIFO(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    return f"{path} is {kind}, not a log file; give a file written with --log"
