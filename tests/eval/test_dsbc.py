"""DSBC metric: hand-computed cases (arithmetic in the comments), the 30 ground truths, the CLI."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from host.cli import main as cli_main
from host.tools.eval import dsbc, dsbc_breakdown

from robots.coco.tasks import load_tasks

GROUND_TRUTHS = [t.ground_truth for t in load_tasks().values() if t.ground_truth]


def test_identical_single_element_is_one() -> None:
    assert dsbc('<face_emo emo="wink_right"/>', '<face_emo emo="wink_right"/>') == 1.0


def test_no_elements_on_either_side_is_one() -> None:
    # D* = 0 -> DSBC defined as 1 (text is ignored)
    assert dsbc("Hello", "Hi there") == 1.0
    assert dsbc("", "") == 1.0


def test_empty_generation_against_one_element() -> None:
    # D* = 1. Layer 0: G = [a], T = [].
    # C_cnt = 1 - |1-0| / max(1,0) = 0; C_ord = 0 / 1 = 0; S_tag = 0
    # S_attr: a has no attributes -> phi = 1 -> S_attr = 1; S_0 = (0 + 1) / 2 = 0.5
    assert dsbc("<a/>", "") == pytest.approx(0.5)
    # with an attribute: E(e) empty -> phi = 0 -> S_0 = 0
    assert dsbc('<a x="1"/>', "just talking") == pytest.approx(0.0)


def test_wrong_attribute_value() -> None:
    # Layer 0: tags match -> C_cnt = 1, C_ord = 1, S_tag = 1.
    # phi = |{(emo,wink_right)} & {(emo,wink_left)}| / 1 = 0 -> S_attr = 0 -> S_0 = 0.5
    assert dsbc('<face_emo emo="wink_right"/>', '<face_emo emo="wink_left"/>') == pytest.approx(0.5)


def test_extra_attribute_is_not_penalised_missing_one_is() -> None:
    # directed: only G's pairs count. G has 2 pairs, T reproduces 1 -> phi = 1/2
    # S_0 = (1 + 0.5) / 2 = 0.75 ; extra attributes on T cost nothing
    assert dsbc('<a x="1" y="2"/>', '<a x="1" z="9"/>') == pytest.approx(0.75)
    assert dsbc('<a x="1"/>', '<a x="1" y="2" z="3"/>') == 1.0


def test_order_swap_keeps_count_but_loses_order() -> None:
    # G = [a, b], T = [b, a]: C_cnt = 1 - 0/2 = 1; C_ord = 0/2 = 0; S_tag = 0.5; S_attr = 1
    # S_0 = (0.5 + 1) / 2 = 0.75
    assert dsbc("<a/><b/>", "<b/><a/>") == pytest.approx(0.75)


def test_over_generation() -> None:
    # G = [a], T = [a, a, b]: tags {a, b}
    # C_cnt = 1 - (|1-2| + |0-1|) / (max(1,2) + max(0,1)) = 1 - 2/3 = 1/3
    # C_ord = 1 / max(1, 3) = 1/3; S_tag = 1/3; S_attr = 1 (a has no attributes)
    # S_0 = (1/3 + 1) / 2 = 2/3
    assert dsbc("<a/>", "<a/><a/><b/>") == pytest.approx(2 / 3)


def test_best_match_attribute_across_candidates() -> None:
    # G = [m(x=1,y=2), m(x=3,y=4)], T = [m(x=1,y=0), m(x=3,y=4)] (same tags -> S_tag = 1)
    # phi(G1) = max(1/2 [T1], 0/2 [T2]) = 1/2 ; phi(G2) = max(0, 2/2) = 1 -> S_attr = 3/4
    # S_0 = (1 + 0.75) / 2 = 0.875
    r = dsbc_breakdown('<m x="1" y="2"/><m x="3" y="4"/>', '<m x="1" y="0"/><m x="3" y="4"/>')
    assert r.layers[0].s_attr == pytest.approx(0.75)
    assert r.score == pytest.approx(0.875)


def test_nested_layers_and_missing_layer() -> None:
    # G: <a x="1"><b/><c/></a><d/>   layers: L0 = [a, d], L1 = [b, c]
    # T: <a x="2"><c/></a>           layers: L0 = [a],    L1 = [c]
    # L0: C_cnt = 1 - (0 + 1)/(1 + 1) = 0.5; C_ord = 1/2; S_tag = 0.5;
    #     phi(a) = 0/1 = 0, phi(d) = 1 (no attrs) -> S_attr = 0.5; S_0 = 0.5
    # L1: C_cnt = 1 - (1 + 0)/(1 + 1) = 0.5; C_ord = [b != c] 0/2 = 0; S_tag = 0.25;
    #     S_attr = (1 + 1)/2 = 1; S_1 = 0.625
    # DSBC = (0.5 + 0.625) / 2 = 0.5625
    r = dsbc_breakdown('<a x="1"><b/><c/></a><d/>', '<a x="2"><c/></a>')
    assert [(l.c_cnt, l.c_ord, l.s_tag, l.s_attr, l.score) for l in r.layers] == [
        pytest.approx((0.5, 0.5, 0.5, 0.5, 0.5)),
        pytest.approx((0.5, 0.0, 0.25, 1.0, 0.625)),
    ]
    assert r.score == pytest.approx(0.5625)


def test_generated_deeper_than_ground_truth() -> None:
    # G: <a/> (1 layer); T: <a><b/></a> (2 layers) -> D* = 2
    # L0: identical -> 1.  L1: G empty, T = [b]: C_cnt = 1 - 1/1 = 0; C_ord = 0/1 = 0;
    #     S_attr = 1 (m = 0) -> S_1 = (0 + 1)/2 = 0.5.   DSBC = (1 + 0.5)/2 = 0.75
    assert dsbc("<a/>", "<a><b/></a>") == pytest.approx(0.75)


def test_text_is_ignored_and_layer_zero_is_top_level() -> None:
    gt = "<wait>Hello</wait><face_emo emo=\"smile\"/>"
    assert dsbc(gt, "Sure! <wait>Hi!</wait> <face_emo emo='smile'/> done") == 1.0
    assert [l.gt_tags for l in dsbc_breakdown(gt, gt).layers] == [("wait", "face_emo")]


def test_malformed_generation_is_scored_not_rejected() -> None:
    # lenient parse of T: "</x>" dropped, unclosed <a> closed at the end -> T = <a><b/></a>
    # G = <a><b/></a> -> identical structure -> 1.0, with warnings reported
    r = dsbc_breakdown("<a><b/></a>", "<a></x><b/>")
    assert r.score == 1.0 and len(r.warnings) == 2
    # a truncated tag is dropped: T = [a] against G = [a, b]
    # C_cnt = 1 - 1/2 = 0.5, C_ord = 1/2, S_tag = 0.5, S_attr = (1 + 0)/2 = 0.5 -> 0.5
    assert dsbc('<a/><b x="1"/>', '<a/><b x="') == pytest.approx(0.5)


def test_malformed_ground_truth_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="ground truth is not a well-formed"):
        dsbc("<a>", "<a/>")


def test_references_are_resolved_before_comparing_attributes() -> None:
    assert dsbc('<say t="a&amp;b"/>', "<say t='a&#38;b'/>") == 1.0


def test_all_thirty_ground_truths_score_one_against_themselves() -> None:
    assert len(GROUND_TRUTHS) == 30
    for gt in GROUND_TRUTHS:
        assert dsbc(gt, gt) == 1.0, gt


def test_perturbed_ground_truths() -> None:
    gts = {i + 1: g for i, g in enumerate(GROUND_TRUTHS)}
    # task 4: <wait>Hello</wait><face_emo emo="smile"/> with the wait dropped:
    # L0: G = [wait, face_emo], T = [face_emo]: C_cnt = 1 - 1/2 = 0.5; C_ord = 0/2 = 0;
    #     S_tag = 0.25; S_attr = (1 + 1)/2 = 1; DSBC = 0.625
    assert dsbc(gts[4], '<face_emo emo="smile"/>') == pytest.approx(0.625)
    # task 23: <head_act action="nod"><move_strides direction="backward" times="3"/></head_act>
    # generated flattened: <head_act action="nod"/><move_strides direction="backward" times="3"/>
    # L0: G = [head_act], T = [head_act, move_strides]: C_cnt = 1 - 1/2 = 0.5; C_ord = 1/2;
    #     S_tag = 0.5; S_attr = 1 -> S_0 = 0.75
    # L1: G = [move_strides], T = []: S_tag = 0; phi = 0 (has attrs, no candidate) -> S_1 = 0
    # DSBC = (0.75 + 0) / 2 = 0.375
    flat = '<head_act action="nod"/><move_strides direction="backward" times="3"/>'
    assert dsbc(gts[23], flat) == pytest.approx(0.375)
    # task 11 with one wrong count: 4 knocks, the 4th with times="3" instead of "4"
    # L0 tags identical -> S_tag = 1; phi = 1, 1, 1, 1/2 -> S_attr = 3.5/4 = 0.875
    # DSBC = (1 + 0.875)/2 = 0.9375
    wrong = gts[11].replace('leg="4" times="4"', 'leg="4" times="3"')
    assert wrong != gts[11]
    assert dsbc(gts[11], wrong) == pytest.approx(0.9375)


def test_cli_prints_score_and_breakdown(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    gen = tmp_path / "gen.xml"
    gen.write_text('<a x="2"><c/></a>')
    assert cli_main(["dsbc", '<a x="1"><b/><c/></a><d/>', f"@{gen}"]) == 0
    out = capsys.readouterr().out
    assert "DSBC = 0.5625" in out and "0.625" in out
    assert cli_main(["dsbc", "<a/>", "<b/>", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    # L0: C_cnt = 1 - 2/2 = 0, C_ord = 0, S_attr = 1 (no attrs) -> 0.5
    assert data["dsbc"] == pytest.approx(0.5) and data["layers"][0]["c_cnt"] == 0.0


def test_cli_reports_bad_ground_truth(capsys: pytest.CaptureFixture[str]) -> None:
    assert cli_main(["dsbc", "<a>", "<a/>"]) == 2
    assert "ground truth" in capsys.readouterr().err
