"""Directed Structured Behavior Correctness (DSBC), the paper's evaluation metric (Sec. 4.1, App. B.1).

Both programs are parsed into element forests with :class:`host.shell.parser.FunctionTokenParser`;
text (speech) is ignored. Layer ``l`` is the ordered sequence of elements at depth ``l``, where depth 0
holds the top-level elements of the fragment (there is no synthetic root). With ``D* = max(d_G, d_T)``
layers (a missing layer is an empty sequence):

* count accuracy  ``C_cnt = 1 - sum_t |N_t^G - N_t^T| / sum_t max(N_t^G, N_t^T)`` (1 if both empty);
* order accuracy  ``C_ord = (1/M) * #{i < min(m, n) : tag(G_i) == tag(T_i)}``, ``M = max(m, n)``;
* ``S_tag = (C_cnt + C_ord) / 2``;
* attribute score ``S_attr = mean over G elements of phi(e)``, ``phi = 1`` if e has no attributes,
  0 if no generated element at that layer has e's tag, otherwise the best fraction of e's
  (name, value) pairs reproduced exactly by one same-tag generated element (``S_attr = 1`` if m = 0);
* ``S_l = (S_tag + S_attr) / 2`` and ``DSBC = mean_l S_l`` (1 when ``D* = 0``).

The ground truth is parsed strictly (a malformed ground truth is a ``ValueError``); the generated
program is parsed in lenient mode so malformed model output is scored, not rejected: stray ``<``/``&``
become text, end-tags that close nothing are dropped, an end-tag naming an ancestor closes the inner
elements, unclosed elements are closed at the end, a truncated tag is dropped.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

from host.shell.parser import (
    EmptyTag,
    EndTag,
    FunctionTokenParser,
    ParseError,
    ParseWarning,
    StartTag,
)

__all__ = ["DSBCResult", "Element", "LayerScore", "dsbc", "dsbc_breakdown", "layers", "parse_forest"]


@dataclass
class Element:
    """One element of a parsed program: tag name, attributes and child elements (text dropped)."""

    tag: str
    attrs: dict[str, str]
    children: list[Element] = field(default_factory=list)


@dataclass(frozen=True)
class LayerScore:
    """The DSBC components at one depth."""

    depth: int
    gt_tags: tuple[str, ...]
    gen_tags: tuple[str, ...]
    c_cnt: float
    c_ord: float
    s_tag: float
    s_attr: float
    score: float


@dataclass(frozen=True)
class DSBCResult:
    """The DSBC score with its per-layer breakdown and the recoveries made parsing the output."""

    score: float
    layers: tuple[LayerScore, ...]
    warnings: tuple[str, ...] = ()


def parse_forest(program: str, strict: bool) -> tuple[list[Element], list[str]]:
    """Parse ``program`` into its top-level elements; return them with any lenient-mode warnings."""
    parser = FunctionTokenParser(strict=strict)
    events = parser.feed(program) + parser.close()
    roots: list[Element] = []
    stack: list[Element] = []
    warnings: list[str] = []
    for ev in events:
        if isinstance(ev, StartTag | EmptyTag):
            el = Element(ev.name, dict(ev.attrs))
            (stack[-1].children if stack else roots).append(el)
            if isinstance(ev, StartTag):
                stack.append(el)
        elif isinstance(ev, EndTag):
            stack.pop()
        elif isinstance(ev, ParseWarning):
            warnings.append(f"{ev.pos}: {ev.message}")
    return roots, warnings


def layers(roots: list[Element]) -> list[list[Element]]:
    """Ordered element sequences by depth (document order within each depth)."""
    out: list[list[Element]] = []
    level = roots
    while level:
        out.append(level)
        level = [child for el in level for child in el.children]
    return out


def _layer_score(depth: int, g: list[Element], t: list[Element]) -> LayerScore:
    m, n = len(g), len(t)
    ng = Counter(e.tag for e in g)
    nt = Counter(e.tag for e in t)
    tags = ng.keys() | nt.keys()
    denom = sum(max(ng[x], nt[x]) for x in tags)
    c_cnt = 1.0 if denom == 0 else 1.0 - sum(abs(ng[x] - nt[x]) for x in tags) / denom
    big_m = max(m, n)
    c_ord = 1.0 if big_m == 0 else sum(g[i].tag == t[i].tag for i in range(min(m, n))) / big_m
    s_tag = (c_cnt + c_ord) / 2
    if m == 0:
        s_attr = 1.0
    else:
        total = 0.0
        for eg in g:
            if not eg.attrs:
                total += 1.0
                continue
            pairs = eg.attrs.items()
            cands = [et for et in t if et.tag == eg.tag]
            if cands:
                total += max(sum(et.attrs.get(k) == v for k, v in pairs) for et in cands) / len(
                    eg.attrs
                )
        s_attr = total / m
    return LayerScore(
        depth=depth,
        gt_tags=tuple(e.tag for e in g),
        gen_tags=tuple(e.tag for e in t),
        c_cnt=c_cnt,
        c_ord=c_ord,
        s_tag=s_tag,
        s_attr=s_attr,
        score=(s_tag + s_attr) / 2,
    )


def dsbc_breakdown(ground_truth: str, generated: str) -> DSBCResult:
    """DSBC of ``generated`` against ``ground_truth`` with per-layer components."""
    try:
        gt_roots, _ = parse_forest(ground_truth, strict=True)
    except ParseError as exc:
        raise ValueError(f"ground truth is not a well-formed function-token program: {exc}") from exc
    gen_roots, warnings = parse_forest(generated, strict=False)
    lg, lt = layers(gt_roots), layers(gen_roots)
    d_star = max(len(lg), len(lt))
    per = tuple(
        _layer_score(
            d, lg[d] if d < len(lg) else [], lt[d] if d < len(lt) else []
        )
        for d in range(d_star)
    )
    score = 1.0 if d_star == 0 else sum(s.score for s in per) / d_star
    return DSBCResult(score=score, layers=per, warnings=tuple(warnings))


def dsbc(ground_truth: str, generated: str) -> float:
    """The DSBC score in [0, 1] of ``generated`` against ``ground_truth``."""
    return dsbc_breakdown(ground_truth, generated).score
