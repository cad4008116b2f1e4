"""Every paper task's ground truth gives the same timeline it gave before scopes and RUN elements.

``data/task_timelines.json`` was written from the shell as it was before ``until``/``timeout``
and RUN-as-element (issue 19) by ``python tests/shell/test_task_timelines_golden.py --write``:
each record's path, function, channel, args, persistent flag, start, end and outcome, on the
virtual clock with the example CoCo functions, in both scheduling modes where the paper's
program has a Sync-First equivalent (``test_tasks.SYNC_FIRST``). Regenerate it only for a
change that is meant to alter the timelines.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from robots.coco.tasks import load_tasks

GOLDEN = Path(__file__).with_name("data") / "task_timelines.json"
TASKS = {i: t.ground_truth for i, t in load_tasks().items() if t.ground_truth}


def _key(tl) -> list[dict]:
    return [{"path": r.path, "function": r.function, "channel": r.channel,
             "args": {k: (v.name if hasattr(v, "name") else v) for k, v in r.args.items()},
             "persistent": r.persistent, "start": r.start, "end": r.end, "outcome": r.outcome} for r in tl]


async def _timelines(make) -> dict[str, list[dict]]:
    from test_tasks import SYNC_FIRST  # noqa: PLC0415 (beside this file)

    out = {}
    for tid, program in sorted(TASKS.items()):
        shell, _ = make()
        out[f"async-first/{tid}"] = _key((await shell.run_text(program)).timeline)
    for tid, program in sorted(SYNC_FIRST.items()):
        shell, _ = make(mode="sync-first")
        out[f"sync-first/{tid}"] = _key((await shell.run_text(program)).timeline)
    return out


def _make(**kw):
    from host.testing.quadruped import SimulatedQuadruped, modules
    from host.shell.registry import Registry
    from host.shell.shell import Shell

    impl = SimulatedQuadruped()
    return Shell(Registry(modules(impl)), **kw), impl


@pytest.mark.anyio
async def test_every_task_timeline_is_unchanged(monkeypatch) -> None:
    monkeypatch.syspath_prepend(str(Path(__file__).parent))
    golden = json.loads(GOLDEN.read_text(encoding="utf-8"))
    now = await _timelines(_make)
    assert sorted(now) == sorted(golden)
    for name in golden:
        assert now[name] == golden[name], name


if __name__ == "__main__" and sys.argv[1:] == ["--write"]:
    import trio
    from trio.testing import MockClock

    sys.path.insert(0, str(Path(__file__).parent))
    data = trio.run(_timelines, _make, clock=MockClock(autojump_threshold=0))
    GOLDEN.parent.mkdir(exist_ok=True)
    GOLDEN.write_text(json.dumps(data, indent=0, sort_keys=True) + "\n", encoding="utf-8")
    print(f"wrote {GOLDEN} ({len(data)} programs)")
