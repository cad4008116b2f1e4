"""Standard output that cannot be written never stops a command: :class:`StdoutGuard`.

:func:`host.cli.main` installs it around every command. It replaces ``sys.stdout`` with a text stream of
the same encoding, error handler and buffering over file descriptor 1 whose lowest layer catches the
:class:`OSError` of a write, so ``print()``, ``sys.stdout.write`` and rich consoles (which look up
``sys.stdout`` when they write) never raise one in the middle of the work:

- EPIPE (the reader left: ``ghostshell run ... | head -1``): the command goes on (a run still writes
  summary.json and timeline.json), its further output is dropped, its exit status is its own and
  nothing is said on stderr (as Unix tools are silent on a closed pipe).
- any other error (ENOSPC on ``> /dev/full``, EIO): the command goes on likewise; at its end one line on
  stderr, ``ghostshell COMMAND: could not write to stdout: No space left on device``, and exit status 1
  unless the command already failed (then its own status).

After the first failure file descriptor 1 is pointed at ``/dev/null``: what is still buffered, the
interpreter's own flush at exit and child processes started later write there, so no ``Exception ignored
... BrokenPipeError`` is printed as Python shuts down. Only the process's own stdout is guarded (``sys.stdout
is sys.__stdout__``, on file descriptor 1): a test's captured stream is left as it is.
"""

from __future__ import annotations

import errno
import io
import os
import sys
import threading
from typing import TYPE_CHECKING, TextIO

from host.commands.errors import print_error

if TYPE_CHECKING:
    from _typeshed import WriteableBuffer

__all__ = ["StdoutGuard"]


class _GuardedFd(io.RawIOBase):
    """File descriptor ``fd`` as a raw binary stream whose writes never raise :class:`OSError`: the first
    failure is handed to ``on_error`` and every write from then on reports all its bytes written."""

    def __init__(self, fd: int, guard: StdoutGuard) -> None:
        super().__init__()
        self._fd = fd
        self._guard = guard

    def writable(self) -> bool:
        return True

    def fileno(self) -> int:
        return self._fd

    def isatty(self) -> bool:
        try:
            return os.isatty(self._fd)
        except OSError:
            return False

    def write(self, b: WriteableBuffer, /) -> int:
        n = memoryview(b).nbytes
        if self._guard.error is not None:
            return n
        try:
            return os.write(self._fd, b)
        except BlockingIOError:  # a non-blocking stdout that is full: the buffer layer above retries
            raise
        except OSError as e:
            self._guard.failed(e)
            return n

    def close(self) -> None:  # fd 1 stays open: the interpreter and child processes still use it
        super().close()


class StdoutGuard:
    """``sys.stdout`` replaced by a stream whose failures are recorded, not raised (see the module docstring).

    :meth:`install` returns None when ``sys.stdout`` is not the process's own (a test's capture, None when
    fd 1 was closed). :meth:`finish` ends the command: flushes, puts the old ``sys.stdout`` back and returns
    the exit status. ``error``: the first write's :class:`OSError`, or None."""

    def __init__(self, original: TextIO, fd: int) -> None:
        self.error: OSError | None = None
        self._original = original
        self._fd = fd
        self._lock = threading.Lock()
        unbuffered = isinstance(getattr(original, "buffer", None), io.RawIOBase)  # python -u
        binary = io.BufferedWriter(_GuardedFd(fd, self), buffer_size=1 if unbuffered else io.DEFAULT_BUFFER_SIZE)
        self.stream = io.TextIOWrapper(binary, encoding=original.encoding, errors=original.errors,
                                       line_buffering=bool(original.line_buffering),
                                       write_through=bool(getattr(original, "write_through", False)))

    @classmethod
    def install(cls) -> StdoutGuard | None:
        """Guard the process's stdout from now on (``sys.stdout`` is the guarded stream); None when it is not
        the process's own stream on fd 1 (nothing is changed then)."""
        original: TextIO | None = sys.stdout
        if original is not sys.__stdout__ or original is None:
            return None
        try:
            fd = original.fileno()
            original.flush()
        except (OSError, ValueError, io.UnsupportedOperation):
            return None
        if fd != 1:
            return None
        guard = cls(original, fd)
        sys.stdout = guard.stream
        return guard

    def failed(self, error: OSError) -> None:
        """Record the first write's failure and point fd 1 at /dev/null (later writes, the flush at exit)."""
        with self._lock:
            if self.error is not None:
                return
            self.error = error
            try:
                null = os.open(os.devnull, os.O_WRONLY)
                try:
                    os.dup2(null, self._fd)
                finally:
                    os.close(null)
            except OSError:
                pass

    def finish(self, command: str | None, status: int) -> int:
        """End the command whose exit status is ``status``: flush what it printed, put the old ``sys.stdout``
        back and return the status to exit with (1 after a write error other than EPIPE, which is named
        in one line on stderr, when ``status`` was 0)."""
        try:
            self.stream.flush()
        except (OSError, ValueError):  # closed by the command, or a non-blocking stdout still full
            pass
        if sys.stdout is self.stream:
            sys.stdout = self._original
        e = self.error
        if e is None or e.errno == errno.EPIPE:
            return status
        try:
            print_error(command, f"could not write to stdout: {e.strerror or e}")
        except OSError:
            pass
        return 1 if status == 0 else status
