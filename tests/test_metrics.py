"""Metrics on small cases computed by hand (the numbers in the comments are the derivations)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lostx.core.errors import InputError
from lostx.evaluation.groundtruth import from_lists, index_aligned
from lostx.evaluation.metrics import evaluate, evaluate_tolerances, max_f1_by_tolerance, pr_curve, recall_at_n


def five_queries():
    """Queries 0-3 each have one true reference (their own index); query 4 has none.

    predictions [0, 1, 3, 3, 2], scores (lower is better) [0.1, 0.2, 0.2, 0.3, 0.4]
    correct     [T, T, F, T, F]   (query 4 has no true reference: any answer is wrong)
    """
    gt = from_lists([[0], [1], [2], [3], []], n_references=5)
    return gt, np.array([0, 1, 3, 3, 2]), np.array([0.1, 0.2, 0.2, 0.3, 0.4])


def test_pr_points_with_a_tie_and_a_query_without_a_true_match():
    gt, pred, score = five_queries()
    ev = evaluate(pred, score, gt)
    c = ev.curve
    # thresholds 0.1 | 0.2 (q1 right, q2 wrong, accepted together) | 0.3 | 0.4 (q4: no true match -> FP)
    np.testing.assert_allclose(c.thresholds, [0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(c.tp, [1, 2, 3, 3])
    np.testing.assert_array_equal(c.fp, [0, 1, 1, 2])
    np.testing.assert_allclose(c.precision, [1, 2 / 3, 3 / 4, 3 / 5])
    np.testing.assert_allclose(c.recall, [1 / 4, 2 / 4, 3 / 4, 3 / 4])  # denominator: 4 matchable queries
    assert ev.n_matchable == 4 and ev.n_queries == 5 and ev.n_answered == 5 and ev.n_correct == 3


def test_tie_is_not_split_in_the_methods_favour():
    gt, pred, score = five_queries()
    ev = evaluate(pred, score, gt)
    # Ordering q1 before q2 inside the tie would give 0.5; the tie is one group with an FP, so 0.25.
    assert ev.recall_at_100p == pytest.approx(0.25)


def test_max_f1_and_average_precision_by_hand():
    gt, pred, score = five_queries()
    ev = evaluate(pred, score, gt)
    # F1 per point: 0.4, 4/7, 0.75, 2/3 -> max 0.75 at threshold 0.3 (P = R = 0.75)
    assert ev.max_f1 == pytest.approx(0.75)
    assert ev.threshold_at_max_f1 == pytest.approx(0.3)
    assert ev.precision_at_max_f1 == pytest.approx(0.75) and ev.recall_at_max_f1 == pytest.approx(0.75)
    np.testing.assert_allclose(ev.curve.f1, [0.4, 4 / 7, 0.75, 2 / 3])
    # AP = 0.25 * 1 + 0.25 * 2/3 + 0.25 * 3/4 + 0 * 3/5
    assert ev.auc_pr == pytest.approx(0.25 + 0.25 * 2 / 3 + 0.25 * 0.75)


def test_recall_over_all_queries_counts_the_unmatchable_query():
    gt, pred, score = five_queries()
    ev = evaluate(pred, score, gt, recall_over="all")
    np.testing.assert_allclose(ev.curve.recall, [0.2, 0.4, 0.6, 0.6])
    assert ev.recall_at_100p == pytest.approx(0.2)
    assert ev.recall_at_n[1] == pytest.approx(3 / 5)


def test_higher_is_better_confidence_gives_the_same_numbers():
    gt, pred, score = five_queries()
    low = evaluate(pred, score, gt)
    high = evaluate(pred, 1.0 - score, gt, higher_is_better=True)
    assert high.recall_at_100p == low.recall_at_100p
    assert high.max_f1 == pytest.approx(low.max_f1) and high.auc_pr == pytest.approx(low.auc_pr)
    np.testing.assert_allclose(high.curve.thresholds, 1.0 - low.curve.thresholds)
    # The same scores read the wrong way round rank the worst first: a different curve.
    flipped = evaluate(pred, score, gt, higher_is_better=True)
    assert flipped.recall_at_100p == 0.0  # best "confidence" 0.4 is query 4, which has no true match


def test_best_scored_query_wrong_means_zero_recall_at_full_precision():
    gt = index_aligned(4, 4, 0)[0]
    pred = np.array([3, 1, 2, 3])  # query 0 wrong, others right
    score = np.array([0.05, 0.2, 0.3, 0.4])  # ... and query 0 is the most confident
    ev = evaluate(pred, score, gt)
    assert ev.recall_at_100p == 0.0
    # later points: TP 1..3 with FP 1 -> P = 1/2, 2/3, 3/4; R = 1/4, 2/4, 3/4; F1 max at the end = 0.75
    assert ev.max_f1 == pytest.approx(0.75)
    assert ev.auc_pr == pytest.approx(0.25 * (1 / 2 + 2 / 3 + 3 / 4))


def test_all_tied_with_one_wrong_answer():
    gt = index_aligned(3, 3, 0)[0]
    ev = evaluate(np.array([0, 1, 0]), np.full(3, 0.5), gt)
    assert len(ev.curve) == 1
    assert ev.recall_at_100p == 0.0
    assert ev.curve.precision[0] == pytest.approx(2 / 3) and ev.curve.recall[0] == pytest.approx(2 / 3)


def test_all_correct():
    gt = index_aligned(4, 4, 0)[0]
    ev = evaluate(np.arange(4), np.array([0.4, 0.1, 0.3, 0.2]), gt, candidates=np.arange(4)[:, None])
    assert (ev.recall_at_100p, ev.max_f1, ev.auc_pr) == (1.0, 1.0, 1.0)
    assert ev.recall_at_n == {1: 1.0, 5: 1.0, 10: 1.0}


def test_all_wrong():
    gt = index_aligned(4, 4, 0)[0]
    ev = evaluate(np.array([1, 2, 3, 0]), np.array([0.4, 0.1, 0.3, 0.2]), gt)
    assert (ev.recall_at_100p, ev.max_f1, ev.auc_pr) == (0.0, 0.0, 0.0)
    assert ev.recall_at_n[1] == 0.0
    assert ev.precision_at_max_f1 == 0.0


def test_abstentions_are_never_accepted_but_stay_in_the_denominator():
    gt = index_aligned(4, 4, 0)[0]
    pred = np.array([0, -1, 2, 3])  # query 1 gives no answer
    score = np.array([0.1, 0.0, 0.2, np.nan])  # query 3 answers with a NaN score: no answer either
    ev = evaluate(pred, score, gt)
    np.testing.assert_array_equal(ev.curve.tp, [1, 2])
    assert ev.n_answered == 2
    assert ev.recall_at_100p == pytest.approx(0.5)
    assert ev.max_f1 == pytest.approx(2 * 1 * 0.5 / 1.5)


def test_no_matchable_query_gives_undefined_recall():
    gt = from_lists([[], []], n_references=3)
    ev = evaluate(np.array([0, 1]), np.array([0.1, 0.2]), gt)
    assert ev.n_matchable == 0
    assert math.isnan(ev.recall_at_100p) and math.isnan(ev.max_f1) and math.isnan(ev.auc_pr)
    assert math.isnan(ev.recall_at_n[1])
    np.testing.assert_array_equal(ev.curve.fp, [1, 2])  # both answers are false positives


def test_recall_at_n_from_candidate_lists():
    gt = from_lists([[0], [5], []], n_references=6)
    cands = np.array([[1, 0, 2], [5, 3, 4], [0, 1, 2]])
    r = recall_at_n(cands, gt, ns=(1, 2, 5))
    assert r == {1: 0.5, 2: 1.0, 5: 1.0}  # query 2 has no true match: not in the denominator
    r_all = recall_at_n(cands, gt, ns=(1, 2), recall_over="all")
    assert r_all == pytest.approx({1: 1 / 3, 2: 2 / 3})


def test_recall_at_n_ignores_padding_and_checks_indices():
    gt = from_lists([[2], [0]], n_references=3)
    assert recall_at_n(np.array([[-1, 2], [1, -1]]), gt, ns=(1, 2)) == {1: 0.0, 2: 0.5}
    with pytest.raises(InputError, match="query 1: candidate reference 7"):
        recall_at_n(np.array([[0, 1], [7, 0]]), gt)


def test_recall_at_n_widens_with_the_tolerance():
    gts = index_aligned(3, 10, [0, 2])
    cands = np.array([[2, 9], [3, 1], [9, 8]])
    assert recall_at_n(cands, gts[0], ns=(1, 2)) == pytest.approx({1: 0, 2: 1 / 3})
    assert recall_at_n(cands, gts[1], ns=(1, 2)) == pytest.approx({1: 2 / 3, 2: 2 / 3})


def test_max_f1_grows_with_the_tolerance():
    pred = np.array([0, 2, 2, 5, 4])
    score = np.array([0.1, 0.2, 0.3, 0.4, 0.5])
    evals = evaluate_tolerances(pred, score, index_aligned(5, 6, [2, 0, 1]))
    tol, f1 = max_f1_by_tolerance(evals)
    np.testing.assert_array_equal(tol, [0, 1, 2])
    # tol 0: correct [T, F, T, F, T] -> max F1 at the end, P = R = 3/5
    # tol 1: [T, T, T, F, T] -> 4/5; tol 2: every prediction within 2 -> 1
    np.testing.assert_allclose(f1, [0.6, 0.8, 1.0])


def test_pr_curve_empty_when_nothing_answered():
    curve = pr_curve(np.zeros(3, bool), np.array([np.nan] * 3), n_positives=3)
    assert len(curve) == 0


def test_bad_shapes_and_indices_are_clear_errors():
    gt = index_aligned(3, 3, 0)[0]
    with pytest.raises(InputError, match="2 predictions and 2 scores for 3 queries"):
        evaluate(np.array([0, 1]), np.array([0.1, 0.2]), gt)
    with pytest.raises(InputError, match="query 2: predicted reference 3 is outside the 3 references"):
        evaluate(np.array([0, 1, 3]), np.array([0.1, 0.2, 0.3]), gt)
    with pytest.raises(InputError, match="recall_over"):
        evaluate(np.array([0, 1, 2]), np.array([0.1, 0.2, 0.3]), gt, recall_over="some")  # type: ignore[arg-type]


def test_recall_interval_is_wilsons_score_interval():
    from lostx.evaluation.significance import recall_interval
    # 27 of 34, z = 1.959964 (z^2 = 3.841459): centre (27 + 1.920729) / 37.841459 = 0.764258,
    # half 1.959964 * sqrt(27 * 7 / 34 + 0.960365) / 37.841459 = 0.132242.
    assert recall_interval(27, 34) == pytest.approx((0.632016, 0.896500), abs=1e-5)
    # None of 10: from 0 to z^2 / (n + z^2) = 3.841459 / 13.841459; all of 10 mirrors it.
    assert recall_interval(0, 10) == pytest.approx((0.0, 0.277533), abs=1e-5)
    assert recall_interval(10, 10) == pytest.approx((1 - 0.277533, 1.0), abs=1e-5)
    # More queries, the same share: a narrower interval around it.
    low, high = recall_interval(270, 340)
    assert 0.632 < low < 27 / 34 < high < 0.8965
    assert all(math.isnan(v) for v in recall_interval(0, 0))
    with pytest.raises(InputError, match="0 <= k <= n, got 5 of 4"):
        recall_interval(5, 4)


def test_sign_test_is_exact_mcnemar():
    from lostx.evaluation.significance import paired_comparison, sign_test
    assert sign_test(0, 5) == pytest.approx(2 / 32)  # both tails of 5 coin tosses all one way
    assert sign_test(1, 9) == pytest.approx(2 * (1 + 10) / 1024)  # C(10, 0) + C(10, 1) of 2^10, both tails
    assert sign_test(9, 1) == sign_test(1, 9)
    assert sign_test(2, 2) == 1.0 and sign_test(0, 0) == 1.0
    first = np.array([True, True, True, False, False, True])
    second = np.array([True, False, False, False, True, True])
    c = paired_comparison(first, second)
    assert (c.n, c.only_first, c.only_second, c.difference) == (6, 2, 1, 1)
    assert c.p_value == pytest.approx(1.0)  # 2 * (1 + 3) / 8, capped at 1
    with pytest.raises(InputError, match="two answers per query"):
        paired_comparison(first, second[:5])


def test_paired_comparison_in_stretches_counts_each_run_once():
    from lostx.evaluation.significance import paired_comparison
    # Seven neighbouring answers turned right together, as a sequence filter's do, and one more apart: 8 queries,
    # 2 stretches against none (p = 0.5, where the 8 queries alone would give 2 / 2^8).
    first = np.array([True, True] + [True] * 7 + [True, True, True, False, True])
    second = np.array([True, True] + [False] * 7 + [True, True, True, False, False])
    assert paired_comparison(first, second).only_first == 8
    c = paired_comparison(first, second, stretches=True)
    assert (c.only_first, c.only_second, c.p_value) == (2, 0, 0.5)
    # Runs of each kind counted apart, a run at either end included.
    a = np.array([True, False, False, True, True, False])
    b = np.array([False, True, True, False, False, True])
    c = paired_comparison(a, b, stretches=True)
    assert (c.only_first, c.only_second) == (2, 2)


def test_summary_gives_recall_at_1_with_its_interval():
    gt, pred, score = five_queries()
    summary = evaluate(pred, score, gt).summary()
    # 3 of the 4 queries with a true reference recalled at 1: centre (3 + 1.920729) / 7.841459 = 0.627528,
    # half 1.959964 * sqrt(3 * 1 / 4 + 0.960365) / 7.841459 = 0.326886.
    assert summary["recall_at_1"] == pytest.approx(0.75)
    assert (summary["n_recalled_at_1"], summary["recall_denominator"]) == (3, 4)
    assert (summary["recall_at_1_low"], summary["recall_at_1_high"]) == pytest.approx((0.300642, 0.954413), abs=1e-5)
