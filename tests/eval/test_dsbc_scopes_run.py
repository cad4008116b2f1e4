"""DSBC and issue 19's scopes and RUN elements.

DSBC scores the program text the LLM wrote (paper, App. B.1), not the timeline: that a RUN's
calls now sit under ``RUN[0]/`` on the timeline changes no score. A ``<RUN id=.../>`` is one
element of the reply, scored as written (a leaf; the skill's program is the library's, not the
reply's), and ``until``/``timeout`` are attributes like any other (a generated attribute the
ground truth lacks is not penalised, one it has and the generation lacks is).
"""

from __future__ import annotations

import pytest

from host.tools.eval.dsbc import dsbc, dsbc_breakdown
from robots.coco.tasks import load_tasks

TASKS = {i: t.ground_truth for i, t in load_tasks().items() if t.ground_truth}


@pytest.mark.parametrize("tid", sorted(TASKS))
def test_ground_truths_still_score_one(tid: int) -> None:
    assert dsbc(TASKS[tid], TASKS[tid]) == 1.0


def test_a_run_is_one_leaf_element_of_the_reply() -> None:
    gt = '<head_act action="nod"/><wave/>'
    r = dsbc_breakdown(gt, '<RUN id="greet"/>')
    assert [layer.gen_tags for layer in r.layers] == [("RUN",)]  # not expanded, no deeper layer
    assert r.score == dsbc(gt, '<other id="greet"/>')  # a RUN is scored as any other wrong tag
    assert dsbc('<RUN id="greet"/>', '<RUN id="greet"/>') == 1.0
    assert dsbc('<RUN id="greet"/>', '<RUN id="wave"/>') < 1.0


def test_scope_attributes_score_as_attributes() -> None:
    gt = '<wait><head_act action="nod"/></wait><wave/>'
    assert dsbc(gt, '<wait until="all"><head_act action="nod"/></wait><wave/>') == 1.0  # extra: not penalised
    gt_any = '<wait until="any" timeout="2"><head_act action="nod"/></wait>'
    assert dsbc(gt_any, gt_any) == 1.0
    assert dsbc(gt_any, '<wait until="any"><head_act action="nod"/></wait>') < 1.0  # the timeout is missing
    assert dsbc(gt_any, '<wait until="all" timeout="2"><head_act action="nod"/></wait>') < 1.0
