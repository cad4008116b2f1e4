"""``ghostshell eval --workers N`` (N >= 2): the jobs in N worker processes, one job at a time each.

Why processes, not tasks of one event loop: a job's host side (shell, motion streaming, the link's
codec, frame logs, the run's plots) is Python and needs about as much CPU as its board's physics
(30 ground-truth jobs: ~22 CPU-s in the host, ~18 CPU-s in the boards). In one process those host
sides share one interpreter lock, so two workers gave 1.12x; each worker in its own process (with
its own board subprocess, as before) lets two of them use two cores.

The parent (:func:`run_in_processes`) starts ``python -m host.tools.eval.workers`` N times (each in
its own session: the terminal's Ctrl-C reaches the parent only), sends each the job function
(:func:`host.tools.eval.sweep.run_job`, pickled by name: this module imports no sweep), the sweep
(:class:`host.tools.eval.sweep.SweepConfig`) and the system prompt, then one ``(task, trial)`` at a
time as the worker finishes the last, so a slow job does not hold back the others' queue. Each
message on the worker's stdin and stdout is a 4-byte big-endian length and a pickle; the worker's
own stdout is its stderr (a stray ``print`` cannot break the stream). Results go to the parent's
``record`` as they come (the same resume log as in-process jobs).

Stops: when the parent is cancelled (Ctrl-C, SIGTERM: :func:`host.commands.eval._sweep_until_signal`)
it closes each worker's stdin and sends it SIGTERM; the worker cancels its running job (the run's
session stops its board, as an in-process job does) and exits; after :data:`STOP_S` s it is killed.
A worker that dies in a job makes that job's record ``status: "worker_error"`` (retried on the next
start, like an LLM error) and is replaced, unless it never finished a job (then it is not restarted:
a worker that cannot start would fail every job the same way).
"""

from __future__ import annotations

import os
import pickle
import signal
import struct
import subprocess
import sys
from collections import deque
from collections.abc import Awaitable, Callable
from typing import IO, Any

import anyio
import anyio.abc
from anyio.streams.buffered import BufferedByteReceiveStream

__all__ = ["STOP_S", "WORKER_ERROR", "JobFunction", "run_in_processes"]

#: wall seconds a worker has, after SIGTERM, to cancel its job and stop its board (the run's link
#: close <= 5 s and board stop <= 5 s, :mod:`host.run.stops`) before it is killed
STOP_S = 12.0
#: the ``status`` of a job whose worker process died while running it
WORKER_ERROR = "worker_error"
_HEADER = struct.Struct(">I")


def _frame(obj: object) -> bytes:
    body = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    return _HEADER.pack(len(body)) + body


async def _receive(reader: BufferedByteReceiveStream) -> Any:
    (size,) = _HEADER.unpack(await reader.receive_exactly(_HEADER.size))
    return pickle.loads(await reader.receive_exactly(size))


#: what a worker runs: ``await job(cfg, task, trial, system)`` -> the job's record (a module-level function)
JobFunction = Callable[[Any, int, int, str], Awaitable[dict[str, Any]]]


async def run_in_processes(job: JobFunction, cfg: Any, jobs: list[tuple[int, int]], system: str,
                           record: Callable[[dict[str, Any]], None], processes: int) -> None:
    """Run ``jobs`` (``(task, trial)`` pairs) of the sweep ``cfg`` in ``processes`` worker processes,
    each as ``await job(cfg, task, trial, system)`` (:func:`host.tools.eval.sweep.run_job`);
    ``record(rec)`` gets each job's record in the order they finish. Returns when every job has a
    record (or the workers that could have run the rest died); cancelling it stops the workers and
    their boards."""
    queue = deque(jobs)
    async with anyio.create_task_group() as tg:
        for _ in range(max(1, min(processes, len(queue)))):
            tg.start_soon(_drive, (job, cfg, system), queue, record)


async def _drive(sweep: tuple[JobFunction, Any, str], queue: deque[tuple[int, int]],
                 record: Callable[[dict[str, Any]], None]) -> None:
    """One worker slot: a worker process fed from ``queue`` until it is empty (replaced if it dies)."""
    while queue:
        finished = await _one_process(sweep, queue, record)
        if finished == 0:
            return  # it died before finishing a job: another would too


async def _one_process(sweep: tuple[JobFunction, Any, str], queue: deque[tuple[int, int]],
                       record: Callable[[dict[str, Any]], None]) -> int:
    """Start one worker and feed it jobs until the queue is empty or it dies; returns the jobs it finished."""
    proc = await anyio.open_process([sys.executable, "-m", "host.tools.eval.workers"], stdin=subprocess.PIPE,
                                    stdout=subprocess.PIPE, stderr=None, start_new_session=True)
    assert proc.stdin is not None and proc.stdout is not None
    reader = BufferedByteReceiveStream(proc.stdout)
    finished = 0
    job: tuple[int, int] | None = None
    first = _frame(sweep)  # goes with the first job: a worker that dies at start fails the job it was given
    try:
        while queue:
            job = queue.popleft()
            await proc.stdin.send(first + _frame(job))
            first = b""
            rec = await _receive(reader)
            job = None
            finished += 1
            record(rec)
        await proc.stdin.aclose()
        await proc.wait()
    except (anyio.EndOfStream, anyio.IncompleteRead, anyio.BrokenResourceError, anyio.ClosedResourceError):
        status = await proc.wait()
        if job is not None:
            task, trial = job
            record({"task": task, "trial": trial, "status": WORKER_ERROR,
                    "error": f"the eval worker process exited (status {status}) while running this job"})
    finally:
        with anyio.CancelScope(shield=True):
            await _stop(proc)
    return finished


async def _stop(proc: anyio.abc.Process) -> None:
    """Close the worker's stdin, SIGTERM it, wait up to :data:`STOP_S` s, then kill it."""
    if proc.returncode is None:
        assert proc.stdin is not None
        try:
            await proc.stdin.aclose()
        except (anyio.BrokenResourceError, OSError):
            pass
        proc.terminate()
        with anyio.move_on_after(STOP_S):
            await proc.wait()
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    await proc.aclose()


# ---- the worker process ----------------------------------------------------------------------------


def _read(inp: IO[bytes]) -> Any:
    """The next message on ``inp``, or None at its end."""
    head = inp.read(_HEADER.size)
    if len(head) < _HEADER.size:
        return None
    (size,) = _HEADER.unpack(head)
    body = inp.read(size)
    if len(body) < size:
        return None
    return pickle.loads(body)


async def _job_until_sigterm(run: JobFunction, cfg: Any, task: int, trial: int,
                             system: str) -> dict[str, Any] | None:
    """One job, cancelled by SIGTERM (then None): its run's session stops its board on the way out."""
    result: list[dict[str, Any]] = []

    async def job(scope: anyio.CancelScope) -> None:
        result.append(await run(cfg, task, trial, system))
        scope.cancel()

    async def watch(scope: anyio.CancelScope) -> None:
        with anyio.open_signal_receiver(signal.SIGTERM) as signals:
            async for _ in signals:
                scope.cancel()
                return

    async with anyio.create_task_group() as tg:
        tg.start_soon(watch, tg.cancel_scope)
        tg.start_soon(job, tg.cancel_scope)
    return result[0] if result else None


def worker_main() -> int:
    """``python -m host.tools.eval.workers``: read the sweep, then run jobs until stdin ends; 0, or 130
    when SIGTERM stopped a job."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent owns the stop (it is in another session anyway)
    inp = sys.stdin.buffer
    out = os.fdopen(os.dup(sys.stdout.fileno()), "wb")
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # anything printed goes to stderr, not into the stream
    first = _read(inp)
    if first is None:
        return 0
    run, cfg, system = first
    while (job := _read(inp)) is not None:
        task, trial = job
        rec = anyio.run(_job_until_sigterm, run, cfg, task, trial, system, backend="asyncio")
        if rec is None:
            return 130
        out.write(_frame(rec))
        out.flush()
    return 0


if __name__ == "__main__":
    sys.exit(worker_main())
