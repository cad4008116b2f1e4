"""``ghostshell eval``: evaluate an LLM the paper's way (DSBC, runs on the board, the native-call ablation).

Offline, without a model: ``--llm ground-truth`` answers every task with its ground truth (micro =
macro = 1.0), ``--llm scripted --replies FILE`` with the replies in FILE (the format of ``chat
--replies``: blocks separated by lines ``---``; either one reply per task in ``--tasks`` order, or
each block headed ``--- task N``; see :func:`host.tools.eval.sweep.replies_for_tasks`). Either shows the
whole report (eval.json, eval.md, eval.png) with no key and no network.

Exit status: 0 every job finished, 1 some job failed (run again to retry it), 2 bad arguments,
130 interrupted (Ctrl-C / SIGTERM: the running jobs are cancelled, their boards stopped; the reports
cover the jobs that finished; the same command resumes).
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from host.commands.modearg import add_mode_argument
from host.commands.errors import print_error
from host.ghost.factory import LLM_SPECS_HELP
from host.commands.outarg import add_no_plots_argument, out_dir, out_dir_problem
from host.commands.robotarg import add_robot_argument, robot_from_args


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the eval options."""
    parser.add_argument("--llm", required=True, metavar="PROVIDER:MODEL",
                        help=f"{LLM_SPECS_HELP}; offline: ground-truth "
                             "(each task answered with its ground truth) or scripted (with --replies FILE)")
    parser.add_argument("--replies", default=None, metavar="FILE",
                        help="--llm scripted: the replies, blocks separated by lines '---' (one per task in --tasks "
                             "order, or each headed '--- task N')")
    add_robot_argument(parser)
    parser.add_argument("--base-url", default=None, metavar="URL", help="the provider's API root (e.g. http://127.0.0.1:8000/v1)")
    parser.add_argument("--api-key", default=None, metavar="KEY", help="default: GHOSTSHELL_LLM_API_KEY, then the provider's variable")
    parser.add_argument("--tasks", default=None, metavar="IDS",
                        help="task ids, e.g. 1-30 or 1,4,7-9 (default: all of the robot's), or 'ablation' for the "
                             "robot's native-call ablation tasks (e.g. ablation:6,9)")
    parser.add_argument("--trials", type=_at_least_one, default=5, metavar="N", help="rounds per task (the paper: 5)")
    parser.add_argument("--workers", type=_at_least_one, default=1, metavar="N", help="jobs at once, each with its own lockstep board")
    parser.add_argument("--out", type=out_dir, default=None, metavar="DIR", help="output folder (default runs/eval-<model>)")
    parser.add_argument("--native-tools", action="store_true",
                        help="expose the functions as provider tool definitions (native function calling)")
    parser.add_argument("--native-exec", choices=("parallel", "sequential"), default="parallel",
                        help="native tool calls of one response: dispatched together after the speech (parallel "
                        "tool calls; one module's calls queue in order) or each to completion in turn")
    parser.add_argument("--no-run", action="store_true", help="score only; do not execute replies on the board")
    add_no_plots_argument(parser, "executed reply", skips_matplotlib=False)
    parser.add_argument("--vocabulary", default=None, metavar="NAME",
                        help="the robot's vocabulary in the prompt (default: the robot's; ghostshell robots show NAME lists them)")
    add_mode_argument(parser)
    parser.add_argument("--format", choices=("code", "xml"), default="code", help="the prompt format (as ghostshell prompt)")
    parser.add_argument("--temperature", type=_temperature, default=None, metavar="T", help="sampling temperature, 0-2")
    parser.add_argument("--paper-model", default=None, metavar="NAME", help="the paper's column to compare with (default: matched from --llm)")
    from host.commands.run import add_mount_argument

    add_mount_argument(parser)
    parser.add_argument("--ray", default=None, metavar="ADDRESS",
                        help="run the jobs on a Ray cluster (needs ghostshell[ray]): its head's HOST:PORT, auto (the "
                             "cluster this machine joined) or 'local' (start one here)")
    parser.add_argument("--quiet", action="store_true",
                        help="no progress (bar and per-job lines); on a terminal a bar shows jobs, ETA and the running micro mean")


def _at_least_one(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {v}")
    return v


def _temperature(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not 0 <= v <= 2:
        raise argparse.ArgumentTypeError(f"a temperature is 0-2, got {text}")
    return v


def _scripted_replies(args: argparse.Namespace, tasks: list[int]) -> dict[int, str] | None:
    """``--replies`` read and mapped onto ``tasks`` (ValueError with one line), or None without it."""
    from host.chat.script import ScriptError, parse_blocks
    from host.commands.inputs import InputError, read_text_input
    from host.tools.eval.sweep import SCRIPTED, replies_for_tasks
    from host.shell.limits import TurnLimits

    if args.llm != SCRIPTED:
        if args.replies is not None:
            raise ValueError("--replies needs --llm scripted")
        return None
    if args.replies is None:
        raise ValueError("--llm scripted replays --replies FILE (one reply per task, blocks separated by '---'); "
                         "without a file use --llm ground-truth")
    try:
        blocks = parse_blocks(read_text_input(args.replies, "--replies", what="replies"), options=("task",))
        replies = replies_for_tasks(blocks, tasks)
    except InputError as e:
        raise ValueError(str(e)) from None
    except (ScriptError, ValueError) as e:
        raise ValueError(f"--replies {args.replies}: {e}") from None
    for task, text in replies.items():
        why = TurnLimits().refuse_reply(text)
        if why is not None:
            raise ValueError(f"--replies {args.replies}: the reply for task {task}: {why}")
    return replies


def build_config(args: argparse.Namespace) -> Any:
    from host.tools.eval.paper import ablation_tasks, hri_tasks, parse_task_spec
    from host.tools.eval.sweep import SweepConfig

    robot = robot_from_args(args, "eval")
    if isinstance(robot, int):
        raise ValueError("")  # the line is printed
    if args.vocabulary is not None and args.vocabulary not in robot.interface.names:
        raise ValueError(f"--vocabulary {args.vocabulary!r}: {robot.name} has {', '.join(robot.interface.names)}")
    if args.paper_model is not None:  # refused now, not noticed in eval.md after a paid sweep
        from host.tools.eval.paper import match_paper_model, paper_models

        columns = paper_models(robot)
        column = args.paper_model if args.paper_model in columns else match_paper_model(args.paper_model, robot)
        if column is None:
            raise ValueError(f"--paper-model {args.paper_model!r}: " + (
                f"the paper's columns are {', '.join(columns)}" if columns else
                f"{robot.name} has no paper results to compare with; leave --paper-model out"))
        args.paper_model = column
    spec = (args.tasks or "").strip()
    suite = "ablation" if spec.lower().startswith("ablation") else "hri"
    if suite == "ablation":  # "ablation" or "ablation:6,9"
        valid = sorted(ablation_tasks(robot))
        if not valid:
            raise ValueError(f"{robot.name} has no native-call ablation tasks (robot.toml [data] paper_results)")
        tasks = parse_task_spec(spec.partition(":")[2] or "all", valid)
    else:
        valid = sorted(hri_tasks(robot))
        if not valid:
            raise ValueError(f"{robot.name} has no tasks with a ground truth to evaluate")
        tasks = parse_task_spec("all" if args.tasks is None else args.tasks, valid)
    if args.no_run and args.no_plots:  # not silently: a user who gave both expected --no-plots to do something
        raise ValueError("--no-plots with --no-run: no reply runs on the board, so no timeline.png / joints.png "
                         "would be drawn anyway; give one of them")
    if args.native_tools and suite != "ablation":
        raise ValueError("--native-tools is the ablation: use it with --tasks ablation")
    if args.trials < 1 or args.workers < 1:
        raise ValueError("--trials and --workers must be at least 1")
    replies = _scripted_replies(args, tasks)
    if replies is not None and args.native_tools:
        raise ValueError("--native-tools needs a provider's tool calls; --llm scripted replays function tokens")
    model = args.llm.split(":", 1)[-1].replace("/", "_") or "model"
    suffix = "-ablation-native" if args.native_tools else ("-ablation" if suite == "ablation" else "")
    out = args.out or Path("runs") / f"eval-{model}{suffix}"
    why = None if args.out else out_dir_problem(out)  # a given --out was checked when it was parsed
    if why is not None:
        raise ValueError(f"the output folder {out} {why}; give another with --out DIR")
    from host.commands.run import mount_problem

    why = mount_problem(args, robot)
    if why is not None:
        raise ValueError(why)
    return SweepConfig(llm=args.llm, tasks=tasks, robot=str(robot.root), robots_dir=args.robots_dir,
                       trials=args.trials, suite=suite, native_tools=args.native_tools,
                       base_url=args.base_url, api_key=args.api_key, workers=args.workers, out=out,
                       vocabulary=args.vocabulary, mode=args.mode, prompt_format=args.format,
                       execute=not args.no_run, temperature=args.temperature, native_exec=args.native_exec,
                       replies=replies, mcp_mounts=tuple(args.mount_mcp), plots=not args.no_plots)


def main(args: argparse.Namespace) -> int:
    """Run the sweep and write the reports; 2 on bad arguments, 1 when every job failed."""
    import anyio

    from host.tools.eval.report import write_reports
    from host.ghost import GhostError

    from host.tools.eval.sweep import GROUND_TRUTH, OFFLINE

    try:
        cfg = build_config(args)
        if cfg.llm == GROUND_TRUTH and cfg.suite != "hri":
            raise ValueError("--llm ground-truth answers tasks with their ground truth; the ablation has none")
        if cfg.llm not in OFFLINE:
            from host.ghost import UnknownSpecError, make_ghost

            try:
                make_ghost(cfg.llm, base_url=cfg.base_url, api_key=cfg.api_key)  # bad spec/no key: once, up front
            except UnknownSpecError as err:  # eval also takes its offline answerers
                raise GhostError(f"{err}, or {GROUND_TRUTH} (offline)") from None
    except (ValueError, GhostError) as err:
        if str(err):
            print_error("eval", str(err))
        return 2

    from host.progress import bar
    from host.tools.eval.report import job_times, sweep_times

    stopped: list[str] = []
    started = time.monotonic()
    scores: list[float] = []
    total = len(cfg.tasks) * cfg.trials
    with bar(f"eval {cfg.llm}", total, quiet=args.quiet, fields=("micro", "failed")) as shown:

        def progress(rec: dict[str, Any], p: Any) -> None:
            what = (f"DSBC {rec['dsbc']:.2f}" if "dsbc" in rec else
                    (f"{'pass' if rec.get('passed') else 'FAIL'}" if "passed" in rec else rec.get("error", "")))
            run = rec.get("run")
            ran = "" if run is None else f", run {run['outcome']}{' (fell)' if run.get('fell') else ''}"
            if "dsbc" in rec:
                scores.append(float(rec["dsbc"]))
            elif "passed" in rec:
                scores.append(1.0 if rec.get("passed") else 0.0)
            if not args.quiet:
                shown.print(f"[{p.skipped + p.finished}/{p.total}] task {rec['task']} trial {rec['trial']}: "
                            f"{what}{ran}{job_times(rec)}")
            shown.update(completed=p.skipped + p.finished, total=p.total,
                         micro=f"{sum(scores) / len(scores):.2f}" if scores else "", failed=len(p.errors) or "")

        try:
            if args.ray:
                from host.tools.eval.ray_backend import run_sweep_on_ray

                records = run_sweep_on_ray(cfg, args.ray, on_result=progress)
            else:
                records = anyio.run(_sweep_until_signal, cfg, progress, stopped, backend="asyncio")
        except (ValueError, GhostError, ImportError) as err:
            print_error("eval", str(err))
            return 2
        except RuntimeError as err:  # a --mount-mcp server that cannot be mounted: one line, usage error
            from host.commands.linkarg import link_exit_status

            if link_exit_status(err) != 2:
                raise
            print_error("eval", str(err))
            return 2
    config = {**asdict(cfg), "out": str(cfg.out), "api_key": None, "paper_model": args.paper_model,
              "sweep_wall_s": round(time.monotonic() - started, 2), "backend": "ray" if args.ray else "local"}
    expected = len(cfg.tasks) * cfg.trials
    if stopped:  # Ctrl-C / SIGTERM: what finished is in results.jsonl; report it, resume later
        if records:
            write_reports(cfg.out, config, records)
        print_error("eval", f"{stopped[0]}: {len(records)} of {expected} jobs done (in {cfg.out / 'results.jsonl'}"
              f"{'; reports for those written' if records else ''}); run the same command again to resume")
        return 130
    summary = write_reports(cfg.out, config, records)
    if cfg.suite == "ablation":
        print(f"completed {summary['completed']}/{summary['tasks']} (paper: {summary['paper']})")
    elif "micro" in summary:
        print(f"micro {summary['micro']:.2f} ± {summary['micro_std']:.2f}, macro {summary['macro']:.2f} ± "
              f"{summary['macro_std']:.2f}; ran clean {summary['ran_clean']}/{summary['runs']}")
    print(sweep_times(summary["timing"]))
    print(f"wrote {cfg.out / 'eval.json'}, eval.md, eval.png")
    if len(records) < expected:
        print_error("eval", f"{expected - len(records)} job(s) failed; run again to retry them")
        return 1
    return 0


async def _sweep_until_signal(cfg: Any, progress: Any, stopped: list[str]) -> list[dict[str, Any]]:
    """The sweep, cancelled by the first SIGINT/SIGTERM (its name then goes into ``stopped``): the
    running jobs stop (their sessions stop their boards); returns the records finished so far."""
    from host.tools.eval.sweep import load_results, ordered, run_sweep
    from host.run.stops import StopSignals

    signals = StopSignals(lambda stop: False)  # no turn of its own to end gracefully: stop the jobs at once
    records: list[dict[str, Any]] = []
    async with signals.guard():
        records = await run_sweep(cfg, progress)
    if signals.first is not None:
        stopped.append(signals.first.message)
        return ordered(cfg, load_results(cfg.out))
    return records
