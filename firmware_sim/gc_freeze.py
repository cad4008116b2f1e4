"""Keep the cyclic garbage collector's full passes off the board's control loop.

CPython's collector (``gc``) walks every tracked container object on a full (generation 2) pass. A
board process holds ~48 000 of them once its model, codecs and transports are loaded, and a full pass
over them took 9-36 ms here (``gc.collect()`` after building CoCo's board, quiet 2-core machine; 25-62 ms
as the realtime board's own passes while ``bench/bench_latency.py`` ran, measured with a ``gc.callbacks``
probe). A realtime board ticks every 2 ms, so each such pass stalled it for 12-30 ticks: frames applied
late, the watchdog nearer, telemetry bunched.

:func:`freeze_heap` moves every object alive at that moment into the collector's permanent generation
(``gc.freeze``, Python 3.7+: "ignore them for all future collections"; O(1), no pass of its own), so
later passes walk only what the board allocated since. Objects still die by reference count as before;
only a reference cycle among the frozen objects would outlive its last use: the board's own state, kept
to the end of the process anyway, and whatever start-up garbage was still uncollected (once, bounded).
No ``gc.collect()`` first: that full pass would add 9-36 ms to every board's start. The host has its own
copy for its turns (:mod:`host.run.turn_gc`): the two ends do not import each other.
"""

from __future__ import annotations

import gc


def freeze_heap() -> int:
    """Freeze every tracked object (``gc.freeze``); returns how many are frozen now. Call it in the
    board's process once everything long-lived is built, before the serve loop; not from library code
    a test process embeds (nothing frozen there would be collected again)."""
    gc.freeze()
    return gc.get_freeze_count()
