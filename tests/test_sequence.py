"""The online sequence filter: exactly a batch computation of the same scores, causal, bounded per step."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.sequence import SequenceFilter, signed

SPEEDS = (-1.2, -0.8, 0.0, 0.5, 0.8, 1.0, 1.2, 2.0)


class GivenCosts:
    """Window costs handed over whole, frame by frame (the filter's :class:`WindowCosts`), counting look-ups."""

    def __init__(self, n_refs: int) -> None:
        self.n_refs = n_refs
        self.frames: dict[int, np.ndarray | None] = {}
        self.looked_up: set[tuple[int, int]] = set()

    def add(self, t, costs) -> None:
        self.frames[t] = costs

    def drop_before(self, t) -> None:
        self.frames = {k: v for k, v in self.frames.items() if k >= t}

    def at(self, times, refs):
        times, refs = np.broadcast_arrays(times, refs)
        self.looked_up |= set(zip(times.ravel().tolist(), refs.ravel().tolist()))
        out = np.full(refs.shape, np.nan)
        for t in np.unique(times):
            costs = self.frames.get(int(t))
            if costs is not None:
                out[times == t] = costs[refs[times == t]]
        return out

    def known(self, times, refs):
        return self.at(times, refs)

    def reset(self) -> None:
        self.frames = {}


def batch_answers(frames: list[tuple[np.ndarray, np.ndarray | None, np.ndarray]], length: int, radius: int,
                  penalty: float, directions: dict[int, int] | None = None) -> list[tuple[float, float, float]]:
    """The straightforward computation: at every frame T, enumerate every trajectory through every anchor
    of the window's frames (with the speeds that frame spawned), add up its costs frame by frame.
    ``directions[t]``: a direction of travel known before frame t, which rules out the trajectories
    anchored earlier that run against it."""
    directions = directions or {}
    answers = []
    for t in range(len(frames)):
        window = list(range(max(0, t - length + 1), t + 1))
        best = None
        for ta in window:
            anchors, costs_a, speeds = frames[ta]
            if costs_a is None:
                continue
            for ra in np.unique(anchors):
                for v in speeds:
                    if any(directions.get(tp, 0) * v < 0 for tp in range(ta + 1, t + 1)):
                        continue
                    total = 0.0
                    for tt in window:
                        costs = frames[tt][1]
                        centre = int(np.rint(ra + v * (tt - ta)))
                        if costs is None or not 0 <= centre < len(costs):
                            total += penalty
                            continue
                        near = [costs[c] for c in range(centre - radius, centre + radius + 1) if 0 <= c < len(costs)]
                        total += float(min(near))
                    key = (total / len(window), abs(v), ra + v * (t - ta), -ta, -v)
                    if best is None or key < best:
                        best = key
        answers.append((np.nan, np.nan, np.inf) if best is None else (best[2], -best[4], best[0]))
    return answers


def synthetic_traverse(rng: np.random.Generator, n_frames: int, n_refs: int) -> list:
    frames = []
    for t in range(n_frames):
        costs = rng.normal(size=n_refs).astype(np.float32)
        true = 5 + t
        costs[true] -= 2.5  # the true place stands out a little
        anchors = np.argsort(costs)[:4]
        speeds = np.array(SPEEDS) if t % 3 else np.array([0.8, 1.0])  # e.g. a tracker narrowing the band
        frames.append((anchors, None if t == 7 else costs, speeds))  # frame 7: no costs (rejected input)
    return frames


@pytest.mark.parametrize("length, radius", [(5, 0), (8, 1), (1, 0)])
def test_online_equals_batch_on_a_synthetic_traverse(rng, length, radius):
    frames = synthetic_traverse(rng, 30, 60)
    online = SequenceFilter(length, SPEEDS, radius, penalty=0.3, costs=GivenCosts(60))
    got = [online.update(c, a, speeds=s) for a, c, s in frames]
    want = batch_answers(frames, length, radius, 0.3)
    for g, (position, speed, score) in zip(got, want):
        np.testing.assert_equal((g.position, g.speed), (position, speed))
        assert g.score == pytest.approx(score, rel=1e-6, abs=1e-6)
    assert sum(np.isnan(g.position) for g in got) == (1 if length == 1 else 0)


def test_online_equals_batch_on_real_nordland_candidates(nordland):
    """Record what the localizer's filter searched over 200 real frames (its anchors, speeds and every
    cost it looked up), recompute in batch from those costs, compare: the batch looks up no cost the
    filter did not."""
    from lostx.core import Config, Localizer
    from lostx.core.build import build_map
    from lostx.core.frame import Frame
    from lostx.core.refmap import ReferenceMap
    from lostx.core.thumbnail import ThumbnailDescriber
    from lostx.replay.folder import folder_traverse
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        summer = folder_traverse(nordland / "summer")
        build_map(summer.subset(range(300, 700)), f"{tmp}/map", describer=ThumbnailDescriber(), progress=False)
        localizer = Localizer(ReferenceMap.open(f"{tmp}/map"), Config())
        n_refs = localizer.map.n_frames
        anchors: list = []
        speeds: list = []
        looked_up = np.full((200, n_refs), np.nan)
        directions: dict[int, int] = {}
        seq, costs = localizer.sequence, localizer.costs
        update, choose, prune, lookup = seq.update, seq._new_anchors, seq.keep_direction, costs.at

        def recording_update(scores, candidates, seeds=None, speeds_=None):
            speeds.append(np.asarray(speeds_).copy())
            return update(scores, candidates, seeds, speeds_)

        def recording_anchors(t, candidates, seeds):
            anchors.append(choose(t, candidates, seeds))
            return anchors[-1]

        def recording_lookup(times, refs):
            values = lookup(times, refs)
            times, refs, out = np.broadcast_arrays(times, refs, values)
            looked_up[times.ravel(), refs.ravel()] = out.ravel()
            return values

        def pruning(sign):
            directions[len(speeds)] = sign  # applied before the update of frame len(speeds)
            return prune(sign)

        seq.update, seq._new_anchors, seq.keep_direction, costs.at = (recording_update, recording_anchors, pruning,
                                                                       recording_lookup)
        winter = folder_traverse(nordland / "winter")
        online = [localizer.step(Frame(i, winter.frame(300 + i).image)) for i in range(200)]
    cfg = Config().sequence
    fed = list(zip(anchors, looked_up, speeds))
    want = batch_answers(fed, cfg.length, cfg.radius, cfg.penalty, directions)
    right = [e for e in online if abs(e.match_index - e.frame_id) <= 1]
    assert len(right) > 100  # the scene is recognised: the comparison covers real, varied answers
    for e, (position, speed, score) in zip(online, want):
        assert e.sequence_score == pytest.approx(score, rel=1e-6, abs=1e-6)
        assert e.speed == speed or e.state == "not_localized"  # the tracker may replace an answer


def test_live_trajectories_are_bounded_whatever_the_map_size(rng):
    for n_refs in (100, 100_000):
        seq = SequenceFilter(10, SPEEDS, 0, 0.0, GivenCosts(n_refs))
        for _ in range(25):
            seq.update(rng.normal(size=n_refs).astype(np.float32), rng.integers(0, n_refs, 20))
        assert len(seq.scores()) <= 10 * 20 * len(SPEEDS)


def test_anchors_are_the_candidates_and_the_lowest_costs_looked_up():
    costs = np.zeros(50)
    costs[[3, 30, 44]] = [-3.0, -2.0, -1.0]  # 3 is where no trajectory passes and no search looks
    given = GivenCosts(50)
    seq = SequenceFilter(4, (1.0,), 0, 0.0, given, anchors=2)
    seq.update(costs, candidates=np.array([10]), seeds=np.array([29, 30, 44, 45]))
    assert sorted(set(seq._anchor_r.tolist())) == [10.0, 30.0, 44.0]
    assert (0, 3) not in given.looked_up and {(0, 29), (0, 45)} <= given.looked_up


def test_warm_up_and_off_map_penalty():
    seq = SequenceFilter(4, (1.0,), 0, penalty=5.0, costs=GivenCosts(3))
    costs = np.zeros(3, dtype=np.float32)
    costs[0] = -1.0
    first = seq.update(costs, np.array([0]))
    assert first.frames == 1 and first.score == pytest.approx(-1.0)
    for _ in range(4):
        result = seq.update(costs, np.array([0]))
    # The newest trajectory through reference 0 runs off the map on the left for the older frames.
    assert result.frames == 4
    assert np.isfinite(result.score)
    assert seq.update(None, np.array([2])).frames == 4  # a frame without costs: no crash, penalty only
