"""Progress on long work (rich): a bar or a spinner on a terminal, nothing anywhere else.

Shown only when standard output is a terminal (``sys.stdout.isatty()``) and ``--quiet`` was not
given (:func:`wanted`); otherwise every helper here is a no-op, so output that goes to a file, a
pipe or a test is exactly what it was without them. Lines printed through :meth:`Bar.print` appear
above a running bar on a terminal and as plain ``print`` lines elsewhere.

* :func:`bar` -> :class:`Bar`: one task with a total (jobs, frames, seconds), its ETA and named
  fields shown after it (e.g. ``micro 0.82``, ``exec/s 5069``);
* :func:`status`: a spinner with a line of text and the time elapsed, for waits of unknown length
  (booting User-Mode Linux).
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator, Sequence
from typing import Any, TextIO

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    SpinnerColumn,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

__all__ = ["Bar", "bar", "status", "wanted"]


def wanted(quiet: bool = False, stream: TextIO | None = None) -> bool:
    """True when progress should be drawn: not ``quiet`` and ``stream`` (stdout) is a terminal."""
    s = stream if stream is not None else sys.stdout
    try:
        return not quiet and bool(s.isatty())
    except (AttributeError, ValueError):  # a closed or fake stream
        return False


class Bar:
    """One progress task (see :func:`bar`); every method is a no-op when progress is not drawn."""

    def __init__(self, progress: Progress | None, description: str, total: float | None, fields: Sequence[str]) -> None:
        self.progress = progress
        self.fields = {name: "" for name in fields}
        self.task = progress.add_task(description, total=total, info="") if progress is not None else None

    @property
    def shown(self) -> bool:
        return self.progress is not None

    def update(self, *, completed: float | None = None, advance: float | None = None, total: float | None = None,
               **fields: Any) -> None:
        """Move the bar and/or set fields (shown as ``name value`` after the bar)."""
        if self.progress is None or self.task is None:
            return
        for k, v in fields.items():
            self.fields[k] = v
        info = "  ".join(f"{k} {v}" for k, v in self.fields.items() if v != "" and v is not None)
        kw: dict[str, Any] = {"info": info}
        if completed is not None:
            kw["completed"] = completed
        if advance is not None:
            kw["advance"] = advance
        if total is not None:
            kw["total"] = total
        self.progress.update(self.task, **kw)

    def print(self, text: str) -> None:
        """A line of output: above the bar on a terminal, a plain line otherwise."""
        if self.progress is not None:
            self.progress.console.print(text, markup=False, highlight=False)
        else:
            print(text, flush=True)


@contextlib.contextmanager
def bar(description: str, total: float | None, *, quiet: bool = False, fields: Sequence[str] = (),
        transient: bool = False, stream: TextIO | None = None) -> Iterator[Bar]:
    """A progress bar for ``total`` units while the block runs (terminal only, see :func:`wanted`)."""
    if not wanted(quiet, stream):
        yield Bar(None, description, total, fields)
        return
    progress = Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                        TimeElapsedColumn(), TextColumn("eta"), TimeRemainingColumn(), TextColumn("{task.fields[info]}"),
                        console=Console(file=stream) if stream is not None else None, transient=transient)
    with progress:
        yield Bar(progress, description, total, fields)


@contextlib.contextmanager
def status(text: str, *, quiet: bool = False, stream: TextIO | None = None) -> Iterator[None]:
    """A spinner with ``text`` and the time elapsed while the block runs (terminal only); gone after it."""
    if not wanted(quiet, stream):
        yield
        return
    progress = Progress(SpinnerColumn(), TextColumn("{task.description}"), TimeElapsedColumn(),
                        console=Console(file=stream) if stream is not None else None, transient=True)
    with progress:
        progress.add_task(text, total=None)
        yield
