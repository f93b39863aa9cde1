"""Spatial layout verification of the top candidates (paper Sec. III-C), vectorised over candidates.

For each candidate c the D channel correspondences (query keypoint k,
reference keypoint k') are filtered in three steps:

1. both channels fire (a constant channel has no keypoint);
2. semantic label consistency: both keypoints carry the same label;
3. the 3x3 neighbourhood density test: a correspondence survives only if no
   other one within its 3x3 neighbourhood is stronger (by descriptor cosine
   similarity), so at most one is retained per 3x3 neighbourhood.

The M survivors are scored by weighted keypoint matching, Eq. 4:

    r_c = sqrt( sum_kk' w_kk' (p_k - p_k')^2 )

with w_kk' the cosine similarity of the D-dim descriptors x_k, x_k',
normalised over the M pairs, and p the x coordinates as a fraction of the
image width, the query's mirrored (p -> 1 - p) when it views the route the
opposite way to the reference. Lower is better. Both heading hypotheses are
scored at once (they share every correspondence): the localizer finds the
heading by comparing them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..config import DensityFilter, Scoring
from ..describe.keypoints import KeypointEvidence
from ..describe.lost import l2_normalise


@dataclass
class Correspondences:
    """The surviving keypoint correspondences of one query-candidate pair."""

    channel: np.ndarray  # (M,) feature channel k
    query_xy: np.ndarray  # (M, 2) grid (x, y) in the query image, not mirrored
    ref_xy: np.ndarray  # (M, 2) grid (x, y) in the reference image
    label: np.ndarray  # (M,) grouped semantic label
    similarity: np.ndarray  # (M,) cosine similarity of x_k and x_k'


@dataclass
class Verification:
    """Scores of C candidates, and the correspondences behind them."""

    scores: np.ndarray  # (C,) lower is better; inf where no usable correspondence survives
    mirror_scores: np.ndarray  # (C,) the same correspondences scored with the query's x mirrored the other way
    n_consistent: np.ndarray  # (C,) correspondences after the label consistency test
    n_matches: np.ndarray  # (C,) M: after the density test
    grid: tuple[int, int]
    _candidate: np.ndarray
    _channel: np.ndarray
    _query_loc: np.ndarray
    _ref_loc: np.ndarray
    _label: np.ndarray
    _similarity: np.ndarray

    def correspondences(self, c: int) -> Correspondences:
        lo, hi = np.searchsorted(self._candidate, [c, c + 1])
        w = self.grid[1]

        def xy(loc: np.ndarray) -> np.ndarray:
            return np.stack([loc[lo:hi] % w, loc[lo:hi] // w], axis=1).astype(np.int32)

        return Correspondences(
            channel=self._channel[lo:hi].astype(np.int32),
            query_xy=xy(self._query_loc),
            ref_xy=xy(self._ref_loc),
            label=self._label[lo:hi],
            similarity=self._similarity[lo:hi].astype(np.float32),
        )


def density_filter(group: np.ndarray, location: np.ndarray, strength: np.ndarray, grid: tuple[int, int], n_groups: int) -> np.ndarray:
    """Keep each correspondence that is the strongest within its 3x3 neighbourhood.

    group: which candidate each correspondence belongs to (neighbourhoods never
    span candidates); location: flat grid location; strength: the ordering key,
    ties going to the lower index. Returns a boolean keep mask. No two kept
    correspondences of a group lie within one cell (Chebyshev) of each other.
    """
    h, w = grid
    if len(location) == 0:
        return np.zeros(0, dtype=bool)
    rank = strength_ranks(strength)
    y, x = location // w + 1, location % w + 1
    padded = np.full((n_groups, h + 2, w + 2), -1, dtype=np.int64)
    np.maximum.at(padded.reshape(-1), (group * (h + 2) + y) * (w + 2) + x, rank)  # flat: 4x faster than by (c, y, x)
    best = padded[:, 0:h, 0:w].copy()
    for dy in range(3):
        for dx in range(3):
            np.maximum(best, padded[:, dy : dy + h, dx : dx + w], out=best)
    return best[group, y - 1, x - 1] == rank


def strength_ranks(strength: np.ndarray) -> np.ndarray:
    """Rank of each of p correspondences: p - 1 for the strongest; among equals the lower index ranks higher
    (the order of a stable sort by falling strength)."""
    p = len(strength)
    # An unstable sort is 5x faster than a stable one. Equal strengths, which it leaves in any order, are put
    # in index order by a second sort of (run of equal strengths, index): integers, all distinct.
    order = np.argsort(-strength)
    ordered = strength[order]
    missing = np.isnan(ordered)
    same = (ordered[1:] == ordered[:-1]) | (missing[1:] & missing[:-1])
    run = np.concatenate([[0], np.cumsum(~same)])
    order = order[np.argsort(run * p + order)]
    rank = np.empty(p, dtype=np.int64)
    rank[order] = np.arange(p - 1, -1, -1)
    return rank


def eq4_weights(group: np.ndarray, similarity: np.ndarray, n_groups: int) -> np.ndarray:
    """w_kk' of Eq. 4: each pair's similarity normalised over its group's pairs.

    Negative similarities get no weight; a group whose similarities are all 0
    weights its pairs equally.
    """
    m = np.bincount(group, minlength=n_groups)
    sim = np.clip(similarity, 0.0, None)
    total = np.bincount(group, sim, minlength=n_groups)
    flat = total[group] <= 0
    return np.where(flat, 1.0 / np.maximum(m[group], 1), sim / np.where(flat, 1.0, total[group]))


def eq4_distance(group: np.ndarray, weight: np.ndarray, p_query: np.ndarray, p_ref: np.ndarray,
                 n_groups: int) -> np.ndarray:
    """Eq. 4 per group with the pairs' weights w_kk': r_c = sqrt(sum w_kk' (p_k - p_k')^2); inf without pairs."""
    r = np.sqrt(np.bincount(group, weight * (p_query - p_ref) ** 2, minlength=n_groups))
    r[np.bincount(group, minlength=n_groups) == 0] = np.inf
    return r


def eq4_score(group: np.ndarray, similarity: np.ndarray, p_query: np.ndarray, p_ref: np.ndarray, n_groups: int) -> np.ndarray:
    """Eq. 4 per group: r_c = sqrt(sum w_kk' (p_k - p_k')^2), w = similarity normalised over the group's pairs
    (:func:`eq4_weights`); a group without pairs scores inf."""
    return eq4_distance(group, eq4_weights(group, similarity, n_groups), p_query, p_ref, n_groups)


def released_score(group: np.ndarray, similarity: np.ndarray, p_query: np.ndarray, p_ref: np.ndarray, lost_distance: np.ndarray) -> np.ndarray:
    """The scoring of the authors' released code (oravus/lostX, match_lost_kc.py), per group:

    d = 1 - similarity, L1-normalised over the pairs; w = max(d) - d;
    score = cosine_distance(p * w, p' * w) / ||w|| / M * LoST distance.

    Where every pair is equally similar (w = 0, e.g. an image against itself)
    the pairs are weighted equally. Degenerate groups score inf.
    """
    n_groups = len(lost_distance)
    m = np.bincount(group, minlength=n_groups).astype(np.float64)
    d = 1.0 - similarity
    total = np.bincount(group, d, minlength=n_groups)
    d = d / np.where(total[group] > 0, total[group], 1.0)
    top = np.full(n_groups, -np.inf)
    np.maximum.at(top, group, d)
    w = top[group] - d
    spread = np.bincount(group, w, minlength=n_groups)
    w = np.where(spread[group] > 0, w, 1.0 / np.maximum(m[group], 1.0))
    a, b = p_query * w, p_ref * w
    ab = np.bincount(group, a * b, minlength=n_groups)
    norms = np.sqrt(np.bincount(group, a * a, minlength=n_groups) * np.bincount(group, b * b, minlength=n_groups))
    w_norm = np.sqrt(np.bincount(group, w * w, minlength=n_groups))
    with np.errstate(divide="ignore", invalid="ignore"):
        score = (1.0 - ab / norms) / w_norm / m * lost_distance
    score[~np.isfinite(score) | (m == 0)] = np.inf
    return np.maximum(score, 0.0)


def pair_similarity(
    query: KeypointEvidence, q_loc: np.ndarray, refs: KeypointEvidence, cand: np.ndarray, r_loc: np.ndarray
) -> np.ndarray:
    """Cosine similarity of x_k (query, at q_loc) and x_k' (candidate cand, at r_loc) for each pair.

    The reference vectors stay sparse: a pair costs as many multiplications as
    its reference slot has non-zero channels. Evidence reduced to unit vectors on
    a map's projection (lostx.core.describe.reduce) is compared by their dot
    products.
    """
    q_rows = query.slot_rows(0, q_loc)
    r_rows = refs.slot_rows(cand, r_loc)
    if query.dims != refs.dims:
        raise ValueError(f"the query's keypoint descriptors have {query.dims} dimensions, the references' "
                         f"{refs.dims} (project the query with the map's projection)")
    if refs.reduced is not None and query.reduced is not None:
        return np.einsum("pk,pk->p", query.reduced[q_rows], refs.reduced[r_rows]).astype(np.float64)
    query_unit = l2_normalise(query.dense_slots()).ravel()
    refs = refs.sparse()  # a live frame's evidence holds its features whole
    starts = refs.slot_offsets[r_rows]
    lengths = refs.slot_offsets[r_rows + 1] - starts
    bounds = np.cumsum(lengths) - lengths  # where each pair's products begin
    entry = np.arange(int(lengths.sum())) + np.repeat(starts - bounds, lengths)
    picked = query_unit[np.repeat(q_rows * refs.feature_dim, lengths) + refs.channels[entry]]
    products = picked * refs.values[entry]
    dots = np.zeros(len(r_rows), dtype=np.float64)
    filled = lengths > 0  # an all-zero slot (possible with signed features) has dot product 0
    if filled.any():
        dots[filled] = np.add.reduceat(products, bounds[filled])
    slot_norm = refs.slot_norms[r_rows]
    return np.where(slot_norm > 0, dots / np.maximum(slot_norm, 1e-30), 0.0)


def verify(
    query: KeypointEvidence,
    refs: KeypointEvidence,
    lost_distance: np.ndarray,
    opposite: bool = False,
    scoring: Scoring = "eq4-lost",
    density: DensityFilter = "query",
) -> Verification:
    """Verify the spatial layout of one query frame against C candidate frames."""
    h, w = refs.grid
    if query.grid != refs.grid:
        raise ValueError(f"query grid {query.grid} differs from reference grid {refs.grid}")
    n_cand, d = refs.keypoints.shape
    kq = query.keypoints[0]
    kr = refs.keypoints
    label_q = query.labels[0][np.maximum(kq, 0)]
    label_r = np.take_along_axis(refs.labels, np.maximum(kr, 0).astype(np.int64), axis=1)
    consistent = (kq >= 0)[None, :] & (kr >= 0) & (label_q[None, :] == label_r)
    cand, chan = np.nonzero(consistent)
    q_loc = kq[chan].astype(np.int64)
    r_loc = kr[cand, chan].astype(np.int64)
    similarity = pair_similarity(query, q_loc, refs, cand, r_loc)
    n_consistent = np.bincount(cand, minlength=n_cand)

    keep = np.ones(len(cand), dtype=bool)
    if density in ("query", "both"):
        keep &= density_filter(cand, q_loc, similarity, (h, w), n_cand)
    if density == "both":
        keep &= density_filter(cand, r_loc, similarity, (h, w), n_cand)
    cand, chan, q_loc, r_loc, similarity = cand[keep], chan[keep], q_loc[keep], r_loc[keep], similarity[keep]

    p_query = (q_loc % w) / max(w - 1, 1)
    p_ref = (r_loc % w) / max(w - 1, 1)
    lost_distance = np.asarray(lost_distance, dtype=np.float64)
    # Both heading hypotheses share the correspondences; only the query's x differs (p -> 1 - p).
    asked, other = (1.0 - p_query, p_query) if opposite else (p_query, 1.0 - p_query)
    scores, mirror_scores = score_pairs(scoring, cand, similarity, (asked, other), p_ref, lost_distance)
    return Verification(
        scores=scores,
        mirror_scores=mirror_scores,
        n_consistent=n_consistent,
        n_matches=np.bincount(cand, minlength=n_cand),
        grid=(h, w),
        _candidate=cand,
        _channel=chan,
        _query_loc=q_loc,
        _ref_loc=r_loc,
        _label=label_q[chan],
        _similarity=similarity,
    )


def score_pairs(scoring: Scoring, group: np.ndarray, similarity: np.ndarray, p_queries: tuple[np.ndarray, ...],
                p_ref: np.ndarray, lost_distance: np.ndarray) -> list[np.ndarray]:
    """Each group's score from its surviving pairs, once for each of the query's x coordinates ``p_queries`` (the
    heading hypotheses; fractions of the width, as ``p_ref``)."""
    if scoring == "released":
        return [released_score(group, similarity, p_query, p_ref, lost_distance) for p_query in p_queries]
    n_groups = len(lost_distance)
    weight = eq4_weights(group, similarity, n_groups)  # the same for every heading
    scores = [eq4_distance(group, weight, p_query, p_ref, n_groups) for p_query in p_queries]
    if scoring == "eq4-lost":
        scores = [np.where(np.isfinite(r), r * np.maximum(lost_distance, 0.0), np.inf) for r in scores]
    return scores
