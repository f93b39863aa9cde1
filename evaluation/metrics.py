"""Place-recognition metrics, defined exactly (the contract is ``docs/metrics.md``; keep the two in step).

Input, per query q: a predicted reference index ``predictions[q]`` and a score
``scores[q]``; by default a lower score is better (a distance), pass
``higher_is_better=True`` for a confidence. A prediction below 0 or a NaN score
is an abstention: the query is never accepted, at any threshold.

- Correct: ``predictions[q]`` is in q's true set (:class:`GroundTruth`).
- Threshold sweep: at threshold t, the accepted queries are those whose score
  is at least as good as t (``score <= t``, or ``>= t`` for a confidence).
  Thresholds are the distinct scores, so queries with tied scores are accepted
  together: a tie is never split in a method's favour.
- TP(t): accepted and correct. FP(t): accepted and not correct, which includes
  every accepted query that has no true reference at all.
- Recall denominator P: the number of queries with at least one true reference
  (``recall_over="matchable"``, the default) or all queries
  (``recall_over="all"``). recall(t) = TP(t) / P; precision(t) = TP(t) / (TP(t) + FP(t)).
- Recall at 100 % precision: the largest recall(t) over thresholds with
  FP(t) = 0 (exactly, on counts); 0 when the best-scored group already holds a
  false positive.
- Max F1: the largest 2PR / (P + R) over the thresholds (0 where TP = 0).
- AUC-PR: average precision, sum over thresholds of (R_k - R_{k-1}) P_k with
  R_0 = 0: a step-wise area with no interpolation and no invented end points.
- Recall@N: the fraction of the P queries with a true reference among the
  first N entries of their candidate list (no threshold).
With P = 0 every recall-based number is NaN: there is nothing to recall.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from lostx.core.errors import InputError
from .groundtruth import GroundTruth
from .significance import recall_interval

RecallOver = Literal["matchable", "all"]
RECALL_AT = (1, 5, 10)


@dataclass(frozen=True)
class PRCurve:
    """One point per distinct score, strictest threshold first (recall never decreases along it)."""

    thresholds: np.ndarray
    """(K,) the score values, in the caller's direction (ascending for lower-is-better)."""
    tp: np.ndarray
    """(K,) true positives accepted at each threshold."""
    fp: np.ndarray
    """(K,) false positives accepted at each threshold."""
    precision: np.ndarray
    recall: np.ndarray
    f1: np.ndarray
    n_positives: int
    """The recall denominator P."""

    def __len__(self) -> int:
        return len(self.thresholds)


@dataclass(frozen=True)
class Evaluation:
    """Every number of one method on one query set at one tolerance."""

    n_queries: int
    n_matchable: int
    """Queries with at least one true reference."""
    n_answered: int
    """Queries with a prediction (not abstained)."""
    n_correct: int
    """Answered queries whose prediction is correct (TP when everything is accepted)."""
    recall_at_100p: float
    max_f1: float
    precision_at_max_f1: float
    recall_at_max_f1: float
    threshold_at_max_f1: float
    """The score threshold reaching max F1 (NaN when there is none)."""
    auc_pr: float
    recall_at_n: dict[int, float]
    curve: PRCurve
    tolerance: float = 0.0
    unit: str = "frames"
    recall_over: RecallOver = "matchable"
    higher_is_better: bool = False

    def summary(self) -> dict[str, float | int | str]:
        """The scalar numbers, JSON-ready (NaN stays NaN; the report writer decides how to spell it)."""
        out: dict[str, float | int | str] = {
            "tolerance": self.tolerance,
            "tolerance_unit": self.unit,
            "recall_at_100p": self.recall_at_100p,
            "max_f1": self.max_f1,
            "precision_at_max_f1": self.precision_at_max_f1,
            "recall_at_max_f1": self.recall_at_max_f1,
            "auc_pr": self.auc_pr,
        }
        for n, value in sorted(self.recall_at_n.items()):
            out[f"recall_at_{n}"] = value
        out["n_recalled_at_1"] = self.recalled_at_1
        out["recall_denominator"] = self.curve.n_positives
        out["recall_at_1_low"], out["recall_at_1_high"] = self.recall_at_1_interval()
        out.update(
            n_queries=self.n_queries,
            n_matchable=self.n_matchable,
            n_answered=self.n_answered,
            n_correct=self.n_correct,
            recall_over=self.recall_over,
        )
        return out

    @property
    def recalled_at_1(self) -> int:
        """The queries recalled at the first answer (Recall@1 times its denominator; 0 where nothing is recalled
        over)."""
        recall = self.recall_at_n.get(1, float("nan"))
        n = self.curve.n_positives
        return round(recall * n) if n and np.isfinite(recall) else 0

    def recall_at_1_interval(self, level: float = 0.95) -> tuple[float, float]:
        """Recall@1's Wilson score interval (:func:`lostx.evaluation.significance.recall_interval`; NaN where
        nothing is recalled over)."""
        return recall_interval(self.recalled_at_1, self.curve.n_positives, level)


def correct_predictions(predictions: np.ndarray, ground_truth: GroundTruth) -> np.ndarray:
    """(n_queries,) bool: the prediction is in the query's true set (abstentions, index < 0, are never correct)."""
    return ground_truth.is_correct(np.asarray(predictions, dtype=np.int64))


def recall_denominator(ground_truth: GroundTruth, recall_over: RecallOver = "matchable") -> int:
    if recall_over == "matchable":
        return int(ground_truth.has_match.sum())
    if recall_over == "all":
        return ground_truth.n_queries
    raise InputError(f"recall_over must be 'matchable' or 'all', got {recall_over!r}")


def pr_curve(
    correct: np.ndarray,
    scores: np.ndarray,
    n_positives: int,
    higher_is_better: bool = False,
    answered: np.ndarray | None = None,
) -> PRCurve:
    """Precision and recall at every distinct score threshold.

    ``correct[q]``: query q's prediction is correct. ``answered[q]`` False (or a NaN
    score) leaves q out of every threshold. ``n_positives`` is the recall denominator.
    """
    correct = np.asarray(correct, dtype=bool)
    scores = np.asarray(scores, dtype=np.float64)
    if correct.shape != scores.shape or correct.ndim != 1:
        raise InputError(f"correct and scores must be 1-D of one length, got {correct.shape} and {scores.shape}")
    keep = ~np.isnan(scores)
    if answered is not None:
        keep &= np.asarray(answered, dtype=bool)
    goodness = scores[keep] if higher_is_better else -scores[keep]
    hits = correct[keep]
    order = np.argsort(-goodness, kind="stable")
    goodness, hits = goodness[order], hits[order]
    # The last position of each run of equal scores: a threshold accepts a whole run or none of it.
    ends = np.flatnonzero(np.r_[goodness[1:] != goodness[:-1], True]) if len(goodness) else np.zeros(0, int)
    tp = np.cumsum(hits)[ends].astype(np.int64)
    fp = (ends + 1 - tp).astype(np.int64)
    precision = tp / np.maximum(tp + fp, 1)
    if n_positives > 0:
        recall = tp / n_positives
    else:
        recall = np.full(len(tp), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        f1 = np.where(tp > 0, 2 * precision * recall / (precision + recall), 0.0)
    thresholds = goodness[ends] if higher_is_better else -goodness[ends]
    return PRCurve(thresholds, tp, fp, precision, recall, f1, int(n_positives))


def recall_at_100_precision(curve: PRCurve) -> float:
    """The largest recall with no false positive accepted; 0 if the strictest threshold already has one."""
    if curve.n_positives == 0:
        return float("nan")
    clean = curve.fp == 0
    return float(curve.recall[clean].max()) if clean.any() else 0.0


def max_f1(curve: PRCurve) -> tuple[float, int]:
    """(max F1, index of the curve point reaching it; -1 when the curve is empty)."""
    if curve.n_positives == 0:
        return float("nan"), -1
    if len(curve) == 0:
        return 0.0, -1
    k = int(np.argmax(curve.f1))  # first (strictest) threshold among equal maxima
    return float(curve.f1[k]), k


def average_precision(curve: PRCurve) -> float:
    """Step-wise area under the PR curve: sum over points of (R_k - R_{k-1}) * P_k, R_0 = 0."""
    if curve.n_positives == 0:
        return float("nan")
    if len(curve) == 0:
        return 0.0
    steps = np.diff(np.r_[0.0, curve.recall])
    return float(np.sum(steps * curve.precision))


def recall_at_n(
    candidates: np.ndarray,
    ground_truth: GroundTruth,
    ns: Sequence[int] = RECALL_AT,
    recall_over: RecallOver = "matchable",
) -> dict[int, float]:
    """Fraction of the recall denominator whose first N candidates hold a true reference, for each N.

    ``candidates`` is (n_queries, k), best first, padded with -1; a list shorter
    than N counts what it has. A query without a true reference never counts
    as recalled (and is in the denominator only with ``recall_over="all"``).
    """
    cands = np.asarray(candidates, dtype=np.int64)
    if cands.ndim == 1:
        cands = cands[:, None]
    if cands.ndim != 2 or len(cands) != ground_truth.n_queries:
        raise InputError(f"candidates must be (n_queries={ground_truth.n_queries}, k), got shape {cands.shape}")
    if cands.size and cands.max() >= ground_truth.n_references:
        q = int(np.argwhere(cands >= ground_truth.n_references)[0, 0])
        raise InputError(
            f"query {q}: candidate reference {int(cands[q].max())} is outside the "
            f"{ground_truth.n_references} references of the ground truth"
        )
    denominator = recall_denominator(ground_truth, recall_over)
    rows = np.repeat(np.arange(len(cands))[:, None], cands.shape[1], axis=1)
    hit = ground_truth.contains(rows, cands)  # (n_queries, k)
    first_hit = np.where(hit.any(axis=1), hit.argmax(axis=1), np.iinfo(np.int64).max)
    out = {}
    for n in ns:
        if n < 1:
            raise InputError(f"Recall@N needs N >= 1, got {n}")
        out[int(n)] = float(np.sum(first_hit < n) / denominator) if denominator else float("nan")
    return out


def evaluate(
    predictions: np.ndarray,
    scores: np.ndarray,
    ground_truth: GroundTruth,
    candidates: np.ndarray | None = None,
    higher_is_better: bool = False,
    recall_over: RecallOver = "matchable",
    ns: Sequence[int] = RECALL_AT,
) -> Evaluation:
    """All metrics of one run against one ground truth.

    ``candidates`` (n_queries, k) best first gives Recall@N; without it the
    predictions are a one-entry list (Recall@N then equals Recall@1 for every N).
    """
    predictions = np.asarray(predictions)
    scores = np.asarray(scores, dtype=np.float64)
    n = ground_truth.n_queries
    if predictions.shape != (n,) or scores.shape != (n,):
        raise InputError(
            f"{len(predictions)} predictions and {len(scores)} scores for {n} queries in the ground truth "
            f"({ground_truth.source or 'ground truth'}); give one per query"
        )
    if not np.issubdtype(predictions.dtype, np.integer):
        if not np.all(np.isfinite(predictions)) or not np.all(predictions == np.round(predictions)):
            raise InputError("predictions must be whole reference indices (-1 for no answer)")
        predictions = predictions.astype(np.int64)
    too_big = np.flatnonzero(predictions >= ground_truth.n_references)
    if len(too_big):
        q = int(too_big[0])
        raise InputError(
            f"query {q}: predicted reference {int(predictions[q])} is outside the "
            f"{ground_truth.n_references} references of the ground truth"
        )
    answered = (predictions >= 0) & ~np.isnan(scores)
    correct = correct_predictions(predictions, ground_truth)
    positives = recall_denominator(ground_truth, recall_over)
    curve = pr_curve(correct, scores, positives, higher_is_better, answered)
    best, k = max_f1(curve)
    nan = float("nan")
    cands = candidates if candidates is not None else np.where(answered, predictions, -1)[:, None]
    return Evaluation(
        n_queries=n,
        n_matchable=int(ground_truth.has_match.sum()),
        n_answered=int(answered.sum()),
        n_correct=int((correct & answered).sum()),
        recall_at_100p=recall_at_100_precision(curve),
        max_f1=best,
        precision_at_max_f1=float(curve.precision[k]) if k >= 0 else nan,
        recall_at_max_f1=float(curve.recall[k]) if k >= 0 else nan,
        threshold_at_max_f1=float(curve.thresholds[k]) if k >= 0 else nan,
        auc_pr=average_precision(curve),
        recall_at_n=recall_at_n(cands, ground_truth, ns, recall_over),
        curve=curve,
        tolerance=ground_truth.tolerance,
        unit=ground_truth.unit,
        recall_over=recall_over,
        higher_is_better=higher_is_better,
    )


def evaluate_tolerances(
    predictions: np.ndarray,
    scores: np.ndarray,
    ground_truths: Sequence[GroundTruth],
    candidates: np.ndarray | None = None,
    higher_is_better: bool = False,
    recall_over: RecallOver = "matchable",
) -> list[Evaluation]:
    """:func:`evaluate` at each ground truth (e.g. each localization radius), in the given order."""
    return [evaluate(predictions, scores, gt, candidates, higher_is_better, recall_over) for gt in ground_truths]


def max_f1_by_tolerance(evaluations: Sequence[Evaluation]) -> tuple[np.ndarray, np.ndarray]:
    """(tolerances, max F1) sorted by tolerance: the paper's max-F1-against-radius curve."""
    tol = np.asarray([e.tolerance for e in evaluations], dtype=np.float64)
    f1 = np.asarray([e.max_f1 for e in evaluations], dtype=np.float64)
    order = np.argsort(tol, kind="stable")
    return tol[order], f1[order]


@dataclass(frozen=True)
class OperatingPoint:
    """What a deployed system gets: the answers it marked ``localized`` (no threshold chosen afterwards)."""

    n_localized: int
    n_right: int
    """Localized answers that are correct."""
    precision: float
    """n_right / n_localized (NaN with none localized)."""
    recall: float
    """n_right / P, P the recall denominator (as for the oracle recall at 100 % precision)."""

    def summary(self, prefix: str = "localized") -> dict[str, float | int]:
        return {f"{prefix}": self.n_localized, f"{prefix}_right": self.n_right,
                f"{prefix}_precision": self.precision, f"{prefix}_recall": self.recall}


def operating_point(predictions: np.ndarray, localized: np.ndarray, ground_truth: GroundTruth,
                    recall_over: RecallOver = "matchable") -> OperatingPoint:
    """Precision and recall of the ``localized`` answers."""
    localized = np.asarray(localized, dtype=bool)
    right = correct_predictions(predictions, ground_truth) & localized
    n_loc, n_right = int(localized.sum()), int(right.sum())
    positives = recall_denominator(ground_truth, recall_over)
    return OperatingPoint(n_loc, n_right, n_right / n_loc if n_loc else float("nan"),
                          n_right / positives if positives else float("nan"))


@dataclass(frozen=True)
class ReliabilityBin:
    low: float
    high: float
    n: int
    """Answers whose confidence falls in [low, high) (the last bin includes 1)."""
    mean_confidence: float
    precision: float
    """Share of them that are correct (NaN when the bin is empty)."""


def reliability(confidences: np.ndarray, correct: np.ndarray,
                edges: Sequence[float] = (0.0, 0.5, 0.9, 0.99, 0.999, 1.0)) -> list[ReliabilityBin]:
    """Binned confidence against measured precision: a confidence that means what it says has, in every
    bin, a precision at least its mean confidence. The bins are finest near 1, where a robot acts."""
    confidences = np.asarray(confidences, dtype=np.float64)
    correct = np.asarray(correct, dtype=bool)
    out = []
    for i, (low, high) in enumerate(zip(edges[:-1], edges[1:])):
        last = i == len(edges) - 2
        inside = (confidences >= low) & ((confidences <= high) if last else (confidences < high))
        n = int(inside.sum())
        out.append(ReliabilityBin(float(low), float(high), n,
                                  float(confidences[inside].mean()) if n else float("nan"),
                                  float(correct[inside].mean()) if n else float("nan")))
    return out
