"""``ghostshell eval --ray ADDRESS``: the same sweep, one Ray task per (task, trial).

Ray (optional extra ``ghostshell[ray]``) schedules the jobs over a cluster; each
task runs :func:`host.tools.eval.sweep.run_job` in its own event loop and starts its
own lockstep board on the node it lands on. The driver appends results to the
same ``results.jsonl`` as they finish (``ray.wait``), so a sweep interrupted on
Ray resumes locally or on Ray alike. ``ADDRESS`` is what ``ray.init`` takes
(``auto``, ``ray://host:10001``), or ``local`` for a fresh local instance.
Run outputs (``runs/``) land on the worker's filesystem under the same path.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict
from typing import Any

from host.tools.eval.sweep import (RESULTS, SweepConfig, SweepProgress, _check_config, load_results, ordered, pending_jobs,
                             recorder, run_job, system_prompt)


def _job(cfg_dict: dict[str, Any], task: int, trial: int, system: str) -> dict[str, Any]:
    import anyio
    from pathlib import Path

    cfg = SweepConfig(**{**cfg_dict, "out": Path(cfg_dict["out"])})
    return anyio.run(run_job, cfg, task, trial, system, backend="asyncio")  # type: ignore[no-any-return]


def run_sweep_on_ray(cfg: SweepConfig, address: str,
                     on_result: Callable[[dict[str, Any], SweepProgress], None] | None = None,
                     num_cpus: int | None = None) -> list[dict[str, Any]]:
    """Run the pending jobs as Ray tasks (at most ``cfg.workers`` in flight); returns all records."""
    try:
        import ray
    except ImportError as err:
        raise ImportError("--ray needs Ray: pip install 'ghostshell[ray]'") from err
    cfg.out.mkdir(parents=True, exist_ok=True)
    _check_config(cfg)
    done = load_results(cfg.out)
    jobs = pending_jobs(cfg, done)
    progress = SweepProgress(total=len(cfg.tasks) * cfg.trials, skipped=len(ordered(cfg, done)))
    system = system_prompt(cfg)
    started_here = not ray.is_initialized()
    if started_here:
        if address == "local":
            ray.init(num_cpus=num_cpus or max(1, cfg.workers), include_dashboard=False, log_to_driver=False)
        else:
            ray.init(address=address, log_to_driver=False)
    try:
        remote = ray.remote(num_cpus=1)(_job)
        cfg_dict = {**asdict(cfg), "out": str(cfg.out.resolve())}
        queue = list(jobs)
        in_flight: list[Any] = []
        with (cfg.out / RESULTS).open("a", encoding="utf-8") as sink:
            record = recorder(sink, done, progress, on_result)
            while queue or in_flight:
                while queue and len(in_flight) < max(1, cfg.workers):
                    task, trial = queue.pop(0)
                    in_flight.append(remote.remote(cfg_dict, task, trial, system))
                ready, in_flight = ray.wait(in_flight, num_returns=1)
                for ref in ready:
                    record(ray.get(ref))
    finally:
        if started_here:
            ray.shutdown()
    return ordered(cfg, done)
