"""The sequence filter's costs: computed for every map frame, or only where the filter looks, and alike."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.match.costs import EveryFrameCosts, HubNormaliser, LookedUpCosts, contrast_normalise
from lostx.core.match.scores import MapScores


def contrast_by_hand(scores: np.ndarray, window: int) -> np.ndarray:
    """SeqSLAM's enhancement over the whole map, one reference at a time: over the window + 1 references centred on
    each, or the window + 1 nearest the map's end."""
    half, n = window // 2, len(scores)
    size = min(2 * half + 1, n)
    out = np.zeros(n)
    for r in range(n):
        first = min(max(0, r - half), n - size)
        near = scores[first : first + size]
        std = np.std(near, ddof=1) if len(near) > 1 else 0.0
        out[r] = (scores[r] - near.mean()) / std if std > 0 else 0.0
    return out


def test_contrast_normalisation_is_the_one_by_hand(rng):
    scores = rng.normal(30.0, 5.0, size=200)
    np.testing.assert_allclose(contrast_normalise(scores, 10), contrast_by_hand(scores, 10), rtol=1e-5, atol=1e-5)


def test_a_valley_at_the_end_of_the_map_stands_out_as_far_as_in_its_middle():
    """A true match's valley spans several map frames; at the map's end its neighbourhood still holds the window + 1
    references (not the half of them on the map's side, mostly the valley itself), so that a vehicle coming onto the
    map there is seen as clearly as anywhere."""
    n, window = 60, 10
    valley = np.array([-3.0, -2.5, -1.5, -0.5])
    middle, end = np.zeros(n), np.zeros(n)
    middle[30:34] = valley
    end[0:4] = valley
    ripple = 0.1 * np.cos(np.arange(n))  # some spread where the scores are flat
    in_middle, at_end = contrast_normalise(middle + ripple, window), contrast_normalise(end + ripple, window)
    at_other_end = contrast_normalise((end + ripple)[::-1], window)
    assert in_middle[30] < -2.0
    assert at_end[0] == pytest.approx(in_middle[30], abs=0.15)
    assert at_other_end[-1] == pytest.approx(at_end[0], abs=1e-6)


def _single_lookup_hubs(contrast: np.ndarray, prior: float) -> np.ndarray:
    """A reference's first cost against the prior (mean 0, variance 1 over ``prior`` frames) and itself."""
    n = prior + 1
    mean = contrast / n
    return (contrast - mean) / np.sqrt(np.maximum((prior + contrast**2) / n - mean**2, 1e-6))


def test_costs_looked_up_anywhere_in_any_order_are_the_whole_map_costs(rng):
    n, window, prior = 300, 10, 100.0
    scores = rng.normal(30.0, 5.0, size=(3, n))
    costs = LookedUpCosts(n, 4, window, prior)
    for t in range(3):
        costs.add(t, MapScores.of_array(scores[t]))
    want = np.stack([_single_lookup_hubs(contrast_by_hand(s, window).astype(np.float32), prior) for s in scores])
    # Each reference looked up once (in one of the frames): its hub statistics then hold that cost alone.
    picked = np.stack([rng.integers(0, 3, 150), rng.permutation(n)[:150]], axis=1)
    for block in np.array_split(picked, 7):  # in several batches, each in random order
        got = costs.at(block[:, 0], block[:, 1])
        np.testing.assert_allclose(got, want[block[:, 0], block[:, 1]], rtol=1e-6, atol=1e-6)
    # Only the neighbourhoods were scored, never a whole frame.
    assert costs.computed < 3 * n


def test_first_frame_costs_are_the_every_frame_costs(rng):
    """Before any history, both sources standardise a cost against the prior and itself alone."""
    n, window, prior = 500, 10, 100.0
    scores = MapScores.of_array(rng.normal(1.0, 0.1, size=n))
    every, looked = EveryFrameCosts(n, 3, window, prior), LookedUpCosts(n, 3, window, prior)
    every.add(0, scores)
    looked.add(0, scores)
    refs = rng.permutation(n)[:100]
    np.testing.assert_allclose(looked.at(np.array(0), refs), every.at(np.array(0), refs), rtol=1e-6, atol=1e-6)
    assert list(every.lowest(0, 5, np.zeros(0, np.int64))) == list(np.argsort(every.at(np.array(0), np.arange(n)))[:5])


def test_a_cost_is_computed_once_and_kept_while_its_frame_is_in_the_window(rng):
    calls = []
    scores = rng.normal(size=100)

    def distances(refs):
        calls.append(len(refs))
        return scores[refs]

    costs = LookedUpCosts(100, 2, 10, 100.0)
    costs.add(0, MapScores(distances, 100))
    first = costs.at(np.array(0), np.array([40, 41]))
    again = costs.at(np.array(0), np.array([41, 40]))
    assert again.tolist() == first[::-1].tolist() and sum(calls) == 12  # 40 and 41 with 5 either side
    np.testing.assert_array_equal(costs.known(np.array(0), np.array([40, 60])), [first[0], np.nan])
    costs.add(1, MapScores(distances, 100))
    assert costs.known(np.array(0), np.array([40])).tolist() == [first[0]]  # frame 0 is still in the window
    costs.add(2, MapScores(distances, 100))  # frame 2 takes frame 0's place
    assert np.isnan(costs.known(np.array(2), np.array([40]))).all()


def test_lowest_costs_among_those_looked_at():
    scores = np.full(50, 5.0)
    scores[[10, 30, 31]] = [1.0, 0.0, 0.5]
    costs = LookedUpCosts(50, 2, 4, 100.0)
    costs.add(0, MapScores.of_array(scores))
    # 30 and 31 are not looked at: the lowest among the others is 10, then its neighbours.
    assert costs.lowest(0, 1, np.array([8, 9, 10, 11, 12, 49, -3, 50])).tolist() == [10]
    # Over every reference, lowest first: 10 stands out more than 30, whose neighbour 31 is close too.
    assert costs.lowest(0, 2, np.arange(50)).tolist() == [10, 30]


def test_removed_frames_get_the_given_worst_score_and_a_frame_without_scores_has_no_cost():
    scores = MapScores.of_array(np.arange(20.0))
    removed = MapScores(scores.distances, 20, removed=slice(5, 8), removed_score=99.0)
    assert removed.at(np.array([4, 5, 7, 8])).tolist() == [4.0, 99.0, 99.0, 8.0]
    costs = LookedUpCosts(20, 2, 4, 100.0)
    costs.add(0, None)
    assert np.isnan(costs.at(np.array(0), np.array([3, 4]))).all()


def test_verified_candidates_keep_their_own_scores():
    scores = MapScores(lambda refs: np.ones(len(refs)), 10, factor=2.0, known=np.array([2, 7]),
                       known_scores=np.array([0.5, 0.25]))
    assert scores.at(np.array([7, 1, 2])).tolist() == [0.25, 2.0, 0.5]
    eq4 = MapScores(lambda refs: np.ones(len(refs)), 10, constant=0.75, known=np.array([3]), known_scores=np.array([0.1]))
    assert eq4.at(np.array([3, 4])).tolist() == [0.1, 0.75]


def test_a_reference_is_normalised_by_its_own_looked_up_costs():
    hubs = HubNormaliser(10, prior=5.0)
    for _ in range(50):
        hubs(np.array([3]), np.array([-2.0]))  # reference 3: looked up again and again, always close
    out = hubs(np.array([3, 4]), np.array([-2.0, -2.0]))
    assert out[1] < -1.4  # reference 4, first looked up now: -2 is unusual for it
    assert out[0] > -0.5  # reference 3: -2 is what it always scores (a hub)


def test_costs_of_one_reference_in_several_frames_all_count():
    hubs = HubNormaliser(5, prior=1.0)
    hubs(np.array([2, 2, 2]), np.array([-1.0, -1.0, -1.0]))
    single = HubNormaliser(5, prior=1.0)
    for _ in range(3):
        single(np.array([2]), np.array([-1.0]))
    assert hubs(np.array([2]), np.array([-1.0]))[0] == pytest.approx(single(np.array([2]), np.array([-1.0]))[0])


def test_hub_normaliser_over_every_reference_removes_a_hub(rng):
    hubs = HubNormaliser(50, prior=5.0)
    for _ in range(200):
        costs = rng.normal(size=50)
        costs[7] -= 3.0  # reference 7 looks like every query
        out = hubs.every(costs)
    assert out.dtype == np.float32
    assert abs(out[7]) < 3.0
    assert abs(np.mean(out)) < 0.5


def test_hub_normaliser_removes_a_hub(rng):
    hubs = HubNormaliser(50, prior=5.0)
    refs = np.arange(50)
    for _ in range(200):
        costs = rng.normal(size=50)
        costs[7] -= 3.0  # reference 7 looks like every query
        out = hubs(refs, costs)
    assert abs(out[7]) < 3.0
    assert abs(np.mean(out)) < 0.5


def test_a_step_looks_up_as_many_scores_whatever_the_map_size():
    """The same traverse through a map of 100,000 frames and one of 1,000,000: as many scores computed."""
    from lostx.core.route.sequence import SequenceFilter, signed

    computed = {}
    for n_refs in (100_000, 1_000_000):
        costs = LookedUpCosts(n_refs, 10, 10, 100.0)
        seq = SequenceFilter(10, tuple(signed((0.8, 1.0, 1.2), stopped=False)), 0, 0.0, costs, anchors=5,
                             neighbourhood=5)
        steps = np.random.default_rng(0)
        for t in range(40):
            true = 500 + t

            def scores(refs, t=t, true=true):  # a score for any map frame, computed only when asked
                return 1.0 + 0.1 * np.sin(refs * 12.9898 + t * 78.233) - 0.5 * (refs == true)

            seeds = np.concatenate([[true], steps.integers(0, 100_000, 9)])
            result = seq.update(MapScores(scores, n_refs), seeds[:3], seeds)
        assert abs(result.position - true) <= 1
        computed[n_refs] = costs.computed / 40
    assert computed[1_000_000] == computed[100_000] < 2_000


def _route_scores(true: int, lookalikes: np.ndarray, t: int):
    """A frame's scores of any map frame, computed only when asked: noise, the true place's valley (3 frames wide)
    and a shallower dip at each look-alike place."""
    def scores(refs):
        noise = np.modf(np.sin(refs * 12.9898 + t * 78.233) * 43758.5453)[0]
        valley = np.clip(1.0 - np.abs(refs - true) / 2.0, 0.0, None)
        near = np.abs(refs[:, None] - (lookalikes + t)[None, :]).min(axis=1) == 0
        return 1.0 + 0.3 * noise - 1.0 * valley - 0.3 * near
    return scores


def _bounded_traverse(n_refs: int, steps: int, first_true_candidate: int = 0):
    """The bounded filter as a city map runs it, over a route through a map of ``n_refs`` frames: each frame's 30
    nearest map frames (seeds) are its true place's neighbourhood and look-alikes around the map, its 10 candidates
    the best of them (the true place among them from frame ``first_true_candidate`` on). Returns the filter, its
    costs and the rows read per frame."""
    from lostx.core.route.sequence import SequenceFilter, signed

    length = 20
    costs = LookedUpCosts(n_refs, length, 10, 100.0)
    seq = SequenceFilter(length, tuple(signed((0.8, 0.9, 1.0, 1.1, 1.2), stopped=False)), 0, 0.0, costs, anchors=20,
                         neighbourhood=5, bound=500)
    # Look-alike places anywhere on the map, apart from each other and the route (on a small map places close
    # together share the rows read, which is not what this measures).
    slots = np.arange((n_refs - 200) // 300) * 300 + 100
    slots = slots[np.abs(slots - 5000) > 500]
    lookalikes = np.sort(np.random.default_rng(3).choice(slots, 25, replace=False))
    rows, results = [], []
    for t in range(steps):
        true = 5000 + t
        scores = MapScores(_route_scores(true, lookalikes, t), n_refs)
        seeds = np.concatenate([true + np.arange(-2, 3), lookalikes + t])
        order = seeds[np.argsort(scores.at(seeds), kind="stable")]
        candidates = order[:10] if t >= first_true_candidate else order[~np.isin(order, true + np.arange(-3, 4))][:10]
        before = costs.computed
        results.append(seq.update(scores, candidates, seeds))
        rows.append(costs.computed - before)
    return seq, rows, results


def test_the_bounded_filter_reads_as_many_rows_on_a_10000_frame_map_as_on_a_million():
    """The design's filter: a step's reads are bounded by the candidates, the window and the speeds, not the map."""
    read = {}
    for n_refs in (10_000, 1_000_000):
        seq, rows, results = _bounded_traverse(n_refs, 80)
        assert abs(results[-1].position - (5000 + 79)) <= 1
        assert len(seq.scores()) <= 500
        read[n_refs] = float(np.median(rows[20:]))  # once the window is full
    assert read[1_000_000] == pytest.approx(read[10_000], rel=0.10)
    assert read[1_000_000] < 3_000


def test_the_bounded_filter_finds_a_place_missing_from_the_first_frames_candidates():
    """The true place is not among the first 10 frames' candidates (the index missed it); its lowest costs around the
    seeds anchor it, and it is the answer well within the window."""
    _, _, results = _bounded_traverse(1_000_000, 40, first_true_candidate=10)
    right = [abs(r.position - (5000 + t)) <= 1 for t, r in enumerate(results)]
    assert right.index(True) < 20 and all(right[20:])
