"""host/tools/eval: evaluation of generated function-token programs (the DSBC metric)."""

from host.tools.eval.dsbc import DSBCResult, LayerScore, dsbc, dsbc_breakdown

__all__ = ["DSBCResult", "LayerScore", "dsbc", "dsbc_breakdown"]
