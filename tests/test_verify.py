"""Keypoints, label consistency, the 3x3 density test and weighted keypoint matching (Eq. 4) on small arrays."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.distance import cosine

from lostx.core.describe.keypoints import KeypointEvidence, argmax_keypoints, frame_evidence
from lostx.core.match.verify import density_filter, eq4_score, pair_similarity, released_score, verify


def test_argmax_keypoints_one_per_channel_and_none_for_dead_channels():
    features = np.zeros((3, 2, 3), dtype=np.float32)
    features[0, 1, 2] = 5.0  # channel 0 peaks at (y=1, x=2) -> flat 5
    features[1, 0, 0] = 1.0
    features[1, 1, 1] = 2.0  # channel 1 peaks at flat 4
    keypoints = argmax_keypoints(features.reshape(3, -1))
    assert keypoints.tolist() == [5, 4, -1]  # channel 2 is constant: no keypoint


def test_evidence_keeps_exact_features_at_keypoint_locations(rng):
    features = rng.random((6, 4, 5)).astype(np.float32) * (rng.random((6, 4, 5)) > 0.6)
    labels = rng.integers(0, 3, (4, 5))
    ev = frame_evidence(features, labels)
    dense = ev.dense_slots()
    flat = features.reshape(6, -1)
    for row, location in enumerate(ev.slot_keys):
        np.testing.assert_array_equal(dense[row], flat[:, location])
    np.testing.assert_allclose(ev.sparse().slot_norms, np.linalg.norm(dense, axis=1), rtol=1e-6)
    assert set(ev.slot_keys.tolist()) == set(ev.keypoints[0][ev.keypoints[0] >= 0].tolist())


def test_density_filter_keeps_one_per_3x3_neighbourhood():
    grid = (5, 5)
    loc = np.array([0, 1, 6, 3, 24, 24])  # (0,0), (0,1), (1,1): mutual neighbours; (0,3); (4,4) twice
    strength = np.array([0.2, 0.9, 0.5, 0.1, 0.7, 0.7])
    group = np.zeros(6, dtype=int)
    keep = density_filter(group, loc, strength, grid, 1)
    # (0,1) is strongest of the first three; (0,3) is 2 cells from (0,1): kept; a tie goes to the lower index
    assert keep.tolist() == [False, True, False, True, True, False]


def test_density_filter_never_keeps_two_neighbours(rng):
    loc = rng.integers(0, 64, 300)
    strength = rng.random(300)
    group = rng.integers(0, 3, 300)
    keep = density_filter(group, loc, strength, (8, 8), 3)
    for g in range(3):
        kept = loc[keep & (group == g)]
        y, x = kept // 8, kept % 8
        cheb = np.maximum(abs(y[:, None] - y[None]), abs(x[:, None] - x[None]))
        assert (cheb[~np.eye(len(kept), dtype=bool)] > 1).all()
        # every dropped one has a stronger neighbour (ties: the lower index is stronger)
        for i in np.flatnonzero(~keep & (group == g)):
            cheb_i = np.maximum(abs(loc // 8 - loc[i] // 8), abs(loc % 8 - loc[i] % 8))
            stronger = (strength > strength[i]) | ((strength == strength[i]) & (np.arange(300) < i))
            assert ((group == g) & (cheb_i <= 1) & stronger).any()


def test_eq4_by_hand():
    group = np.array([0, 0, 1])
    similarity = np.array([1.0, 3.0, 0.5])
    p_query = np.array([0.0, 0.5, 0.2])
    p_ref = np.array([0.4, 0.5, 0.2])
    r = eq4_score(group, similarity, p_query, p_ref, 3)
    # candidate 0: w = (0.25, 0.75); r = sqrt(0.25 * 0.4^2 + 0.75 * 0) = 0.2
    assert r[0] == pytest.approx(0.2)
    assert r[1] == pytest.approx(0.0)
    assert r[2] == np.inf  # no pairs


def test_released_score_matches_the_formula_by_hand():
    similarity = np.array([0.9, 0.6, 0.3, 0.8])
    p_query = np.array([0.1, 0.4, 0.7, 0.9])
    p_ref = np.array([0.2, 0.3, 0.9, 0.6])
    d = (1 - similarity) / (1 - similarity).sum()
    w = d.max() - d
    expected = cosine(p_query * w, p_ref * w) / np.linalg.norm(w) / 4 * 0.37
    got = released_score(np.zeros(4, dtype=int), similarity, p_query, p_ref, np.array([0.37]))
    assert got[0] == pytest.approx(expected)


def _image_features(rng, d=12, h=6, w=8) -> tuple[np.ndarray, np.ndarray]:
    features = (rng.random((d, h, w)) ** 4).astype(np.float32)
    labels = rng.integers(0, 3, (h, w)).astype(np.uint8)
    return features, labels


def test_pair_similarity_equals_dense_cosine(rng):
    fq, lq = _image_features(rng)
    refs = [_image_features(rng) for _ in range(3)]
    query = frame_evidence(fq, lq)
    batch = KeypointEvidence.stack([frame_evidence(f, lab) for f, lab in refs])
    cand = np.array([0, 1, 2, 2])
    chan = np.array([0, 3, 5, 7])
    q_loc = query.keypoints[0][chan]
    r_loc = batch.keypoints[cand, chan]
    got = pair_similarity(query, q_loc, batch, cand, r_loc)
    for i, (c, k) in enumerate(zip(cand, chan)):
        a = fq.reshape(12, -1)[:, q_loc[i]]
        b = refs[c][0].reshape(12, -1)[:, r_loc[i]]
        assert got[i] == pytest.approx(a @ b / np.linalg.norm(a) / np.linalg.norm(b), rel=1e-5)


def test_label_consistency_drops_pairs_with_different_labels(rng):
    features, labels = _image_features(rng)
    query = frame_evidence(features, labels)
    relabelled = frame_evidence(features, (labels + 1) % 3)  # same keypoints, every label different
    result = verify(query, relabelled, np.array([0.5]), density="off")
    assert result.n_consistent.tolist() == [0]
    assert result.scores[0] == np.inf
    same = verify(query, frame_evidence(features, labels), np.array([0.5]), density="off")
    assert same.n_consistent[0] == (query.keypoints[0] >= 0).sum()
    assert same.scores[0] == 0.0  # identical images: every keypoint at the same x


@pytest.mark.parametrize("scoring", ["eq4", "eq4-lost", "released"])
def test_mirror_image_with_opposite_scores_as_well_as_itself(rng, scoring):
    features, labels = _image_features(rng)
    image = frame_evidence(features, labels)
    mirror = frame_evidence(features[:, :, ::-1].copy(), labels[:, ::-1].copy())
    distance = np.array([0.3])
    own = verify(image, image, distance, scoring=scoring)
    flipped = verify(mirror, image, distance, opposite=True, scoring=scoring)
    unflipped = verify(mirror, image, distance, opposite=False, scoring=scoring)
    assert flipped.scores[0] == pytest.approx(own.scores[0])
    assert flipped.n_matches[0] == own.n_matches[0] > 0
    assert unflipped.scores[0] > own.scores[0]


def test_verify_ranks_the_right_candidate_among_several(rng):
    features, labels = _image_features(rng)
    query = frame_evidence(features, labels)
    shifted = frame_evidence(np.roll(features, 3, axis=2), np.roll(labels, 3, axis=1))
    others = [frame_evidence(*_image_features(rng)) for _ in range(3)]
    batch = KeypointEvidence.stack([others[0], shifted, frame_evidence(features, labels), others[1], others[2]])
    result = verify(query, batch, np.full(5, 0.4))
    assert int(np.argmin(result.scores)) == 2
    corr = result.correspondences(2)
    np.testing.assert_array_equal(corr.query_xy, corr.ref_xy)
    assert len(corr.channel) == result.n_matches[2]
