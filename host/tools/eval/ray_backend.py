"""``ghostshell eval --ray ADDRESS``: the same sweep, one Ray task per (task, trial).

Ray (optional extra ``ghostshell[ray]``) schedules the jobs over a cluster; each
task runs :func:`host.tools.eval.sweep.run_job` in its own event loop and starts its
own lockstep board on the node it lands on. The driver appends results to the
same ``results.jsonl`` as they finish (``ray.wait``), so a sweep interrupted on
Ray resumes locally or on Ray alike. ``ADDRESS`` is what ``ray.init`` takes
(``auto``: the cluster this machine belongs to, ``HOST:6379`` a head's GCS address, ``ray://HOST:10001``
its Ray Client server), or ``local`` for a fresh local instance.
Run outputs (``runs/``) land on the worker's filesystem under the same (absolute) path.

An address that does not answer is refused before anything is written, in one line
(:class:`RayUnreachable`, a ``ValueError``: ``ghostshell eval`` exits 2, a link or port that cannot be
used): ``HOST:PORT`` forms are first tried with a plain TCP connect of :data:`PROBE_S` s (``ray.init``
itself would retry for minutes and then print a traceback).
"""

from __future__ import annotations

import socket
from collections.abc import Callable
from dataclasses import replace
from typing import Any
from urllib.parse import urlsplit

from host.tools.eval.sweep import (RESULTS, SweepConfig, SweepProgress, _check_config, load_results, ordered, pending_jobs,
                             recorder, run_job, system_prompt)


#: wall seconds the TCP probe of a ``HOST:PORT`` address waits for the head to accept
PROBE_S = 5.0


class RayUnreachable(ValueError):
    """The ``--ray`` address does not lead to a running Ray cluster (one line: the address and why)."""


def host_port(address: str) -> tuple[str, int] | None:
    """``(host, port)`` of ``HOST:PORT`` or ``ray://HOST:PORT`` (IPv6 in brackets), None for ``auto``,
    ``local`` or a form without a port. RayUnreachable for a port that is not a number 1-65535."""
    if address in ("auto", "local") or ":" not in address:
        return None
    parts = urlsplit(address if "://" in address else f"//{address}")
    try:
        port = parts.port
    except ValueError:
        raise RayUnreachable(f"--ray {address}: the port is not a number 1-65535") from None
    if port is None or not parts.hostname:
        return None
    if not 0 < port < 65536:
        raise RayUnreachable(f"--ray {address}: the port is not a number 1-65535")
    return parts.hostname, port


def probe(address: str, timeout: float = PROBE_S) -> None:
    """Raise RayUnreachable unless ``address`` (a ``HOST:PORT`` form) accepts a TCP connection in ``timeout`` s."""
    target = host_port(address)
    if target is None:
        return
    try:
        with socket.create_connection(target, timeout=timeout):
            pass
    except OSError as err:
        why = "no answer in {:g} s".format(timeout) if isinstance(err, TimeoutError) else (err.strerror or str(err))
        raise RayUnreachable(f"--ray {address}: cannot reach a Ray cluster there ({why}); start one with "
                             "'ray start --head' and give the address it prints") from None


def connect(address: str, num_cpus: int) -> None:
    """``ray.init`` for ``address`` (``local``: a fresh instance of ``num_cpus`` CPUs); RayUnreachable
    (one line) when there is no cluster there."""
    import ray

    if address == "local":
        ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
        return
    probe(address)
    try:
        ray.init(address=address, log_to_driver=False)
    except (ConnectionError, RuntimeError, ValueError) as err:  # e.g. auto with no cluster on this machine
        if address == "auto" and "Could not find any running Ray instance" in str(err):
            raise RayUnreachable("--ray auto: no Ray cluster runs on this machine; start one "
                                 "with 'ray start --head', or give its address") from None
        first = (str(err).strip().splitlines() or [type(err).__name__])[0]
        raise RayUnreachable(f"--ray {address}: {first}") from None


def _job(cfg: SweepConfig, task: int, trial: int, system: str) -> dict[str, Any]:
    """One (task, trial) in a Ray worker: :func:`run_job` in its own event loop; the record also
    names the Ray node that ran it (``ray_node``, the node id's first 12 hex digits)."""
    import anyio
    import ray

    rec: dict[str, Any] = anyio.run(run_job, cfg, task, trial, system, backend="asyncio")
    rec["ray_node"] = ray.get_runtime_context().get_node_id()[:12]
    return rec


def run_sweep_on_ray(cfg: SweepConfig, address: str,
                     on_result: Callable[[dict[str, Any], SweepProgress], None] | None = None,
                     num_cpus: int | None = None) -> list[dict[str, Any]]:
    """Run the pending jobs as Ray tasks (at most ``cfg.workers`` in flight); returns all records."""
    try:
        import ray
    except ImportError as err:
        raise ImportError("--ray needs Ray: pip install 'ghostshell[ray]'") from err
    started_here = not ray.is_initialized()
    if started_here:  # first: an address that does not answer is refused before anything is written
        connect(address, num_cpus or max(1, cfg.workers))
    try:
        cfg.out.mkdir(parents=True, exist_ok=True)
        _check_config(cfg)
        done = load_results(cfg.out)
        jobs = pending_jobs(cfg, done)
        progress = SweepProgress(total=len(cfg.tasks) * cfg.trials, skipped=len(ordered(cfg, done)))
        system = system_prompt(cfg)
        remote = ray.remote(num_cpus=1)(_job)
        shipped = replace(cfg, out=cfg.out.resolve())  # as it is (asdict would flatten the mount specs)
        queue = list(jobs)
        in_flight: list[Any] = []
        with (cfg.out / RESULTS).open("a", encoding="utf-8") as sink:
            record = recorder(sink, done, progress, on_result)
            while queue or in_flight:
                while queue and len(in_flight) < max(1, cfg.workers):
                    task, trial = queue.pop(0)
                    in_flight.append(remote.remote(shipped, task, trial, system))
                ready, in_flight = ray.wait(in_flight, num_returns=1)
                for ref in ready:
                    record(ray.get(ref))
    finally:
        if started_here:
            ray.shutdown()
    return ordered(cfg, done)
