"""Keep the cyclic garbage collector's full passes out of a turn.

CPython's collector walks every tracked container object on a full (generation 2) pass. A host with
the shell, the link, the SDKs and MuJoCo loaded holds ~285 000 of them, and a full pass over them took
27-130 ms in the host of ``bench/bench_latency.py`` (a ``gc.callbacks`` probe on a 2-core machine shared
with other work; the emulated board's own passes took 25-62 ms, see :mod:`firmware_sim.gc_freeze`). One such
pass inside a turn holds the event loop past the streamer's 60 ms lookahead and delays every token and
frame behind it.

:func:`frozen_heap` moves every object alive when the first turn of the process starts into the
collector's permanent generation (``gc.freeze``, Python 3.7+; O(1): whole generation lists are moved),
so the passes during the turn walk only what was allocated since. When the last open turn ends it moves
them back into the oldest generation (``gc.unfreeze``): cycles among them that died meanwhile are freed
by the next full pass, which CPython starts by its own thresholds, typically soon after (while the
turn's artefacts are written), not inside the next turn. Turns that overlap (``eval --workers``) share
one frozen period: only the turn that opens it freezes, so each period holds one snapshot and cyclic
garbage cannot pile up across overlapping turns. A process that froze its heap for good before (a fuzz
harness) is left as it is. Objects still die by reference count as before.

The board process has its own copy (:mod:`firmware_sim.gc_freeze`): the two ends do not import each other.
"""

from __future__ import annotations

import contextlib
import gc
import threading
from collections.abc import Iterator

_lock = threading.Lock()
_open = 0  # turns inside frozen_heap() in this process
_froze = False  # the open period's freeze is ours (to undo when the last turn ends)


@contextlib.contextmanager
def frozen_heap() -> Iterator[None]:
    """Freeze the heap (``gc.freeze``) while any such block is open in the process; unfreeze when the
    last one exits (also on an exception or cancellation). Nestable and safe from several threads."""
    global _open, _froze
    with _lock:
        if _open == 0 and gc.get_freeze_count() == 0:
            gc.collect(1)  # a young pass (~1 ms): cycles that already died are not frozen with the rest
            gc.freeze()
            _froze = True
        _open += 1
    try:
        yield
    finally:
        with _lock:
            _open -= 1
            if _open == 0 and _froze:
                gc.unfreeze()
                _froze = False


def turns_frozen() -> int:
    """How many :func:`frozen_heap` blocks are open in this process (0: the heap is not frozen by them)."""
    return _open
