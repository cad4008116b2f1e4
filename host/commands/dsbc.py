"""``ghostshell dsbc GT GEN``: score a generated program against a ground truth (DSBC)."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from rich.console import Console
from rich.table import Table

from host.commands.errors import print_error
from host.commands.inputs import STDIN, InputError, read_text_input
from host.tools.eval.dsbc import dsbc_breakdown


def _load(arg: str, what: str) -> str:
    """A program given inline, as ``@FILE``, or ``-`` for standard input; :class:`InputError` when it
    cannot be read or is empty (an empty program is refused as every command refuses empty input)."""
    if arg.startswith("@"):
        return read_text_input(arg[1:], what, what="function tokens")
    if arg == "-":
        return read_text_input(STDIN, what, what="function tokens")
    text = arg
    if not text.strip():
        raise InputError(f"{what} is empty ({'standard input' if arg == '-' else 'an empty argument'}); "
                         "give function tokens, @FILE or -")
    return text


def configure(parser: argparse.ArgumentParser) -> None:
    """Add the dsbc arguments."""
    parser.add_argument("ground_truth", metavar="GT", help="ground-truth program, @FILE or -")
    parser.add_argument("generated", metavar="GEN", help="generated program, @FILE or -")
    parser.add_argument("--json", action="store_true", help="print the breakdown as JSON")


def main(args: argparse.Namespace) -> int:
    """Print the DSBC score with its per-layer breakdown; exit 2 on unreadable or malformed GT."""
    console = Console()
    try:
        gt = _load(args.ground_truth, "GT")
        gen = _load(args.generated, "GEN")
        result = dsbc_breakdown(gt, gen)
    except (OSError, ValueError) as exc:  # InputError is a ValueError; a malformed GT one too
        print_error("dsbc", str(exc))
        return 2
    if args.json:
        print(
            json.dumps(
                {
                    "dsbc": result.score,
                    "layers": [asdict(layer) for layer in result.layers],
                    "warnings": list(result.warnings),
                },
                indent=1,
            )
        )
        return 0
    table = Table(title="DSBC per layer (depth 0 = top-level elements)")
    for col in ("depth", "ground truth tags", "generated tags", "C_cnt", "C_ord", "S_tag",
                "S_attr", "S_l"):
        table.add_column(col, justify="right" if col[0] in "CSd" else "left")
    for layer in result.layers:
        table.add_row(
            str(layer.depth),
            " ".join(layer.gt_tags) or "-",
            " ".join(layer.gen_tags) or "-",
            f"{layer.c_cnt:.3f}",
            f"{layer.c_ord:.3f}",
            f"{layer.s_tag:.3f}",
            f"{layer.s_attr:.3f}",
            f"{layer.score:.3f}",
        )
    if result.layers:
        console.print(table)
    for w in result.warnings:
        console.print(f"[yellow]warning (generated):[/yellow] {w}", highlight=False)
    console.print(f"DSBC = {result.score:.4f}", highlight=False)
    return 0
