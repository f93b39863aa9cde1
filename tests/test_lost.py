"""LoST descriptor, paper Eq. 1-3, its class-mean windows and normalisation, on hand-checkable arrays."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.build import _windowed
from lostx.core.describe.camera import Geometry
from lostx.core.config import CameraConfig
from lostx.core.describe.classes import ClassGroups
from lostx.core.describe.describer import DescribedFrame, TrailingMeans
from lostx.core.errors import InputError
from lostx.core.frame import Frame
from lostx.core.describe.lost import (
    DescriptorStats,
    RunningStandardiser,
    centred_window,
    class_means,
    l2_normalise,
    lost_descriptor,
    standardise,
    window_means,
)


def test_class_means_eq2_by_hand():
    # D = 2 channels, N = 4 locations; labels: two road (0), one building (1), one sky (3).
    x = np.array([[1.0, 3.0, 5.0, 7.0], [2.0, 4.0, 6.0, 8.0]], dtype=np.float32)
    labels = np.array([0, 0, 1, 3])
    mu, present = class_means(x, labels, n_groups=3)
    np.testing.assert_allclose(mu[0], [2.0, 3.0])  # mean of locations 0 and 1
    np.testing.assert_allclose(mu[1], [5.0, 6.0])
    np.testing.assert_allclose(mu[2], [0.0, 0.0])  # vegetation absent
    assert present.tolist() == [True, True, False]


def test_lost_eq1_by_hand():
    x = np.array([[1.0, 3.0], [0.0, 4.0]], dtype=np.float32)  # D = 2, N = 2
    m = np.array([[0.75, 0.25], [0.5, 0.5]], dtype=np.float32)  # m_is for two classes
    mu = np.array([[2.0, 1.0], [0.0, 0.0]], dtype=np.float32)
    # L_0 = 0.75 * |(2,1) - (1,0)| + 0.25 * |(2,1) - (3,4)| = 0.75*(1,1) + 0.25*(1,3) = (1.0, 1.5)
    # L_1 = 0.5 * (1, 0) + 0.5 * (3, 4) = (2, 2)
    expected = np.concatenate([np.array([1.0, 1.5]) / np.hypot(1.0, 1.5), np.array([2.0, 2.0]) / np.hypot(2, 2)])
    np.testing.assert_allclose(lost_descriptor(x, m, mu), expected, rtol=1e-6)


def test_lost_blocks_are_unit_or_zero(rng):
    x = rng.random((16, 50)).astype(np.float32)
    m = rng.random((3, 50)).astype(np.float32)
    m[2] = 0.0  # a class with zero probability everywhere contributes a zero block
    mu = rng.random((3, 16)).astype(np.float32)
    blocks = lost_descriptor(x, m, mu).reshape(3, 16)
    np.testing.assert_allclose(np.linalg.norm(blocks[:2], axis=1), 1.0, rtol=1e-6)
    assert np.all(blocks[2] == 0)


def test_window_means_skip_frames_without_the_class():
    mus = np.array([[[2.0]], [[0.0]], [[4.0]]])  # T = 3, G = 1, D = 1
    present = np.array([[True], [False], [True]])
    mean, any_present = window_means(mus, present)
    assert mean[0, 0] == pytest.approx(3.0)  # (2 + 4) / 2, the absent frame does not pull towards 0
    assert any_present.tolist() == [True]
    _, none = window_means(mus, np.zeros_like(present))
    assert none.tolist() == [False]


@pytest.mark.parametrize(
    "index, length, window, expected",
    [(0, 100, 15, (0, 8)), (50, 100, 15, (43, 58)), (99, 100, 15, (92, 100)), (5, 10, 15, (0, 10)), (3, 10, 1, (3, 4))],
)
def test_centred_window_clips_at_sequence_ends(index, length, window, expected):
    span = centred_window(index, length, window)
    assert (span.start, span.stop) == expected


def _fake_frames(n: int, rng: np.random.Generator) -> tuple[list[Frame], list[DescribedFrame]]:
    frames, described = [], []
    for i in range(n):
        present = rng.random(2) > 0.3
        means = rng.random((2, 3)).astype(np.float32) * present[:, None]
        described.append(DescribedFrame(None, None, None, means, present, None))  # type: ignore[arg-type]
        frames.append(Frame(id=i, image=np.full((1, 1, 3), i, np.uint8)))
    return frames, described


@pytest.mark.parametrize("n, window", [(1, 15), (10, 15), (40, 15), (40, 5), (7, 1)])
def test_streamed_reference_window_equals_brute_force(rng, n, window):
    frames, described = _fake_frames(n, rng)
    lookup = {id(f.image): d for f, d in zip(frames, described)}
    as_is = Geometry(CameraConfig(), None, "squash", None)
    out = list(_windowed(frames, lambda image: lookup[id(image)], as_is, window))
    assert [(j, f.id) for j, f, *_ in out] == [(i, i) for i in range(n)]
    for j, (_, _, d, mu, _) in enumerate(out):
        span = centred_window(j, n, window)
        chosen = described[span.start : span.stop]
        expected, _ = window_means(np.stack([c.means for c in chosen]), np.stack([c.present for c in chosen]))
        assert d is described[j]
        np.testing.assert_allclose(mu, expected)


def test_trailing_query_means_use_no_future_frame(rng):
    _, described = _fake_frames(6, rng)
    trailing = TrailingMeans(window=3)
    for t, d in enumerate(described):
        got = trailing(d)
        past = described[max(0, t - 2) : t + 1]
        expected, _ = window_means(np.stack([p.means for p in past]), np.stack([p.present for p in past]))
        np.testing.assert_allclose(got, expected)


def test_standardise_uses_given_statistics(rng):
    refs = rng.random((20, 8)).astype(np.float32)
    stats = DescriptorStats.of(refs)
    normalised = standardise(refs, stats.mean, stats.std)
    np.testing.assert_allclose(np.linalg.norm(normalised, axis=1), 1.0, rtol=1e-5)
    # before the final L2 normalisation each dimension has zero mean over the set
    unit = l2_normalise(refs)
    z = (unit - stats.mean) / stats.std
    np.testing.assert_allclose(z.mean(axis=0), 0.0, atol=1e-5)
    np.testing.assert_allclose(normalised, l2_normalise(z), rtol=1e-4, atol=1e-6)


def test_running_standardiser_is_causal_and_pools_the_prior(rng):
    refs = rng.random((30, 6))
    queries = rng.random((5, 6)) + 0.5
    prior = DescriptorStats.of(refs)
    running = RunningStandardiser(prior, prior_frames=2.0)
    outputs = [running(q) for q in queries]
    for t in range(len(queries)):
        seen = l2_normalise(queries[: t + 1])
        n = 2.0 + t + 1
        mean = (2.0 * prior.mean + seen.sum(axis=0)) / n
        second = (2.0 * (prior.std.astype(np.float64) ** 2 + prior.mean**2) + (seen**2).sum(axis=0)) / n
        std = np.sqrt(second - mean**2)
        np.testing.assert_allclose(outputs[t], standardise(queries[t], mean.astype(np.float32), std.astype(np.float32)),
                                   rtol=1e-4, atol=1e-6)
    running.reset()
    np.testing.assert_allclose(running(queries[0]), outputs[0], rtol=1e-6)
    fixed = RunningStandardiser(prior, running=False)
    np.testing.assert_allclose(fixed(queries[3]), standardise(queries[3], prior.mean, prior.std), rtol=1e-6)


def test_class_groups_sum_member_probabilities():
    names = ("other", "road", "building", "house", "tree", "sky")
    groups = ClassGroups.from_spec({"road": ["road"], "building": ["building", "house"]}, names)
    assert groups.label_names == ("road", "building", "other", "tree", "sky")
    probs = np.array([0.1, 0.2, 0.3, 0.25, 0.05, 0.1], dtype=np.float32).reshape(6, 1, 1)
    grouped = groups.group(probs)[:, 0, 0]
    np.testing.assert_allclose(grouped, [0.2, 0.55, 0.1, 0.05, 0.1], rtol=1e-6)
    assert grouped.argmax() == 1  # building + house beat every single class


def test_class_groups_reject_unknown_and_overlapping_names():
    names = ("road", "building", "house")
    with pytest.raises(InputError, match="no class 'tree'.*road, building, house"):
        ClassGroups.from_spec({"vegetation": ["tree"]}, names)
    with pytest.raises(InputError, match="'house' is in both groups"):
        ClassGroups.from_spec({"a": ["house"], "b": ["house", "road"]}, names)
