"""The online sequence filter: exactly a batch computation of the same scores, causal, bounded per step."""

from __future__ import annotations

import numpy as np
import pytest

from lostx.core.match.costs import RingCosts
from lostx.core.route.sequence import SequenceFilter, signed

SPEEDS = (-1.2, -0.8, 0.0, 0.5, 0.8, 1.0, 1.2, 2.0)


def batch_answers(frames: list[tuple[np.ndarray, np.ndarray | None, np.ndarray]], length: int, radius: int,
                  penalty: float, directions: dict[int, int] | None = None,
                  switch: float = np.inf) -> list[tuple[float, float, float]]:
    """The straightforward computation: at every frame T, enumerate every trajectory through every anchor
    of the window's frames (with the speeds that frame spawned), add up its costs frame by frame; for one that
    enters the map within the window, where its frames before that counted at the lowest sum any trajectory had over
    them, plus ``switch``, cost less, that.
    ``directions[t]``: a direction of travel known before frame t, which rules out the trajectories
    anchored earlier that run against it."""
    directions = directions or {}
    n_refs = next(len(costs) for _, costs, _ in frames if costs is not None)
    answers = []
    for t in range(len(frames)):
        window = list(range(max(0, t - length + 1), t + 1))
        found = []
        for ta in window:
            anchors, costs_a, speeds = frames[ta]
            if costs_a is None:
                continue
            for ra in np.unique(anchors):
                for v in speeds:
                    if any(directions.get(tp, 0) * v < 0 for tp in range(ta + 1, t + 1)):
                        continue
                    row, on_map = [], []
                    for tt in window:
                        costs = frames[tt][1]
                        centre = int(np.rint(ra + v * (tt - ta)))
                        on_map.append(0 <= centre < n_refs)
                        if costs is None or not 0 <= centre < len(costs):
                            row.append(penalty)
                            continue
                        near = [costs[c] for c in range(centre - radius, centre + radius + 1) if 0 <= c < len(costs)]
                        row.append(float(min(near)))
                    found.append((row, on_map, ra, v, ta))
        lowest_before = [min((sum(other[:e]) for other, *_ in found), default=0.0) for e in range(len(window))]
        best = None
        for row, on_map, ra, v, ta in found:
            total = sum(row)
            entered = on_map.index(True) if True in on_map else len(window)
            if 0 < entered < len(window):
                total = min(total, lowest_before[entered] + switch + sum(row[entered:]))
            key = (total / len(window), abs(v), ra + v * (t - ta), -ta, -v)
            if best is None or key < best:
                best = key
        answers.append((np.nan, np.nan, np.inf) if best is None else (best[2], -best[4], best[0]))
    return answers


def given_costs(length: int, speeds: tuple[float, ...], radius: int, penalty: float, n_refs: int,
                switch: float = np.inf) -> SequenceFilter:
    """A filter over costs given whole, anchored at the candidates it is given."""
    return SequenceFilter(length, speeds, radius, penalty, RingCosts(n_refs, length), switch=switch)


def synthetic_traverse(rng: np.random.Generator, n_frames: int, n_refs: int, first: int = 5) -> list:
    """Frames whose true place is map frame ``first + t`` (off the map while that is negative)."""
    frames = []
    for t in range(n_frames):
        costs = rng.normal(size=n_refs).astype(np.float32)
        true = first + t
        if 0 <= true < n_refs:
            costs[true] -= 2.5  # the true place stands out a little
        anchors = np.argsort(costs)[:4]
        speeds = np.array(SPEEDS) if t % 3 else np.array([0.8, 1.0])  # e.g. a tracker narrowing the band
        frames.append((anchors, None if t == 7 else costs, speeds))  # frame 7: no costs (rejected input)
    return frames


@pytest.mark.parametrize("length, radius, switch", [(5, 0, np.inf), (8, 1, np.inf), (1, 0, np.inf), (8, 1, 1.5),
                                                    (5, 0, 2.0), (8, 0, 4.0)])
def test_online_equals_batch_on_a_synthetic_traverse(rng, length, radius, switch):
    # With a switch cost the vehicle comes onto the map at frame 6, so that entering trajectories take part.
    frames = synthetic_traverse(rng, 30, 60, first=5 if np.isinf(switch) else -6)
    online = given_costs(length, SPEEDS, radius, 0.3, 60, switch)
    got = [online.update(c, a, None, s) for a, c, s in frames]
    want = batch_answers(frames, length, radius, 0.3, switch=switch)
    if np.isfinite(switch):
        # The switch cost moves some answers here: the comparison covers the entering rule.
        unswitched = batch_answers(frames, length, radius, 0.3, switch=np.inf)
        assert any(a[0] != b[0] for a, b in zip(want, unswitched))
    for g, (position, speed, score) in zip(got, want):
        np.testing.assert_equal((g.position, g.speed), (position, speed))
        assert g.score == pytest.approx(score, rel=1e-6, abs=1e-6)
    assert sum(np.isnan(g.position) for g in got) == (1 if length == 1 else 0)


def test_online_equals_batch_on_real_nordland_candidates(nordland):
    """Record what the localizer feeds the filter over 200 real frames, recompute in batch, compare."""
    from lostx.core import Config, Localizer
    from lostx.core.build import build_map
    from lostx.core.frame import Frame
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.core.describe.thumbnail import ThumbnailDescriber
    from lostx.replay.folder import folder_traverse
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        summer = folder_traverse(nordland / "summer")
        build_map(summer.subset(range(300, 700)), f"{tmp}/map", describer=ThumbnailDescriber(), progress=False)
        localizer = Localizer(ReferenceMap.open(f"{tmp}/map"), Config())
        made, recorded = localizer._sequence_filter, []

        def recording_filter(route, cue=False):
            """A filter as the localizer makes it, recording what it is fed."""
            sequence = made(route, cue)
            fed: list = []
            directions: dict[int, int] = {}
            original, prune, anchored = sequence.update, sequence.keep_direction, sequence._new_anchors

            def recording(scores, candidates, seeds=None, speeds=None, progress=None):
                fed.append([None, None, np.asarray(speeds).copy()])
                return original(scores, candidates, seeds, speeds, progress)

            def anchoring(t, candidates, seeds, ends):
                anchors = anchored(t, candidates, seeds, ends)
                # What the filter was given: the frame's anchors and its cost of every reference.
                fed[-1][:2] = anchors.copy(), sequence.costs.at(np.array(t), np.arange(sequence.costs.n_refs))
                return anchors

            def pruning(sign):
                directions[len(fed)] = sign  # applied before the update of frame len(fed)
                return prune(sign)

            sequence.update, sequence.keep_direction, sequence._new_anchors = recording, pruning, anchoring
            recorded.append((sequence, fed, directions))
            return sequence

        localizer._sequence_filter = recording_filter
        localizer.reset()
        winter = folder_traverse(nordland / "winter")
        online = [localizer.step(Frame(i, winter.frame(300 + i).image)) for i in range(200)]
    # The filter that answered every frame (the heading never turned) was fed all 200.
    fed, directions = next((f, d) for sequence, f, d in recorded if sequence is localizer.sequence)
    assert len(fed) == 200 and all(costs is not None for _, costs, _ in fed)
    cfg = Config().sequence
    want = batch_answers(fed, cfg.length, cfg.radius, cfg.penalty, directions, cfg.switch_cost)
    right = [e for e in online if abs(e.match_index - e.frame_id) <= 1]
    assert len(right) > 100  # the scene is recognised: the comparison covers real, varied answers
    fresh = given_costs(cfg.length, tuple(signed(cfg.speeds, stopped=True)), cfg.radius, cfg.penalty, 400,
                        cfg.switch_cost)
    for (anchors, costs, speeds), (position, speed, score) in zip(fed, want):
        got = fresh.update(costs, anchors, None, speeds)
        assert (got.position, got.speed) == (position, speed)
        assert got.score == pytest.approx(score, rel=1e-6, abs=1e-6)


def test_live_trajectories_are_bounded_whatever_the_map_size(rng):
    for n_refs in (100, 100_000):
        seq = given_costs(10, SPEEDS, 0, 0.0, n_refs)
        for _ in range(25):
            seq.update(rng.normal(size=n_refs).astype(np.float32), rng.integers(0, n_refs, 20))
        assert len(seq.scores()) <= 10 * 20 * len(SPEEDS)


def test_warm_up_and_off_map_penalty():
    seq = given_costs(4, (1.0,), 0, 5.0, 3)
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



def entering_the_map(switch: float) -> tuple[list[float], list[float]]:
    """The answers of a filter (window 12 frames, speed 1) while a vehicle drives 8 frames off the map past a
    look-alike of map frames 30-37 (cost -1.5 each), then enters the map at its frame 0 (cost -1.6 each frame on,
    the look-alike's line then 0); and each answer's margin, the best own mean elsewhere less its own."""
    seq = given_costs(12, (1.0,), 0, 0.0, 60, switch)
    answers, margins = [], []
    for t in range(16):
        costs = np.zeros(60, dtype=np.float32)
        if t < 8:
            costs[30 + t] = -1.5
        else:
            costs[t - 8] = -1.6
        result = seq.update(costs, np.array([30 + t if t < 8 else t - 8]))
        answers.append(result.position)
        margins.append(seq.runner_up(result.position, 5) - result.mean)
    return answers, margins


def test_a_vehicle_entering_the_map_is_followed_once_it_leads_the_look_alike_by_the_switch_cost():
    """Entering costs J = 4: the true line, its 8 frames off the map counted at the look-alike's -12, leads by J
    after 3 frames on the map (-12 + 4 - 4.8), at frame 10; counting those frames as average ones it must wait until
    the look-alike's have left the window (-1.6 x 6 against -1.5 x 6 at frame 13). The confidence weighs the lines'
    own means: just after entering the answer's own evidence is still below the look-alike's (no margin); it leads
    once its own frames do."""
    switched, margins = entering_the_map(4.0)
    assert switched[7] == 37 and switched[9] == 39  # two frames on the map do not yet outweigh J
    assert switched[10:] == [float(t - 8) for t in range(10, 16)]
    assert margins[10] == pytest.approx((-12.0 + 4.8) / 11, abs=1e-6)  # negative: not confident
    assert margins[15] == pytest.approx((-6.0 + 12.8) / 12, abs=1e-6)
    own_means, _ = entering_the_map(np.inf)
    assert own_means[12] == 42 and own_means[13:] == [float(t - 8) for t in range(13, 16)]


def test_only_a_trajectory_entering_the_map_takes_over_by_its_last_frames():
    """A steady track (cost -1 a frame over the 8-frame window) and a line whose last three frames cost -2.5 each:
    on the map all along, its own mean (-7.5) stays above the track's (-8), and it has nothing to take over from;
    entering the map at those frames, it pays J = 4 for the five before them, counted at the track's -5: -8.5."""
    def newest(first: int) -> float:
        seq = given_costs(8, (1.0,), 0, 0.0, 80, 4.0)
        for t in range(10):
            costs = np.zeros(80, dtype=np.float32)
            costs[10 + t] = -1.0
            if t >= 7:
                costs[first + t] = -2.5
            result = seq.update(costs, np.array([10 + t, first + t]))
        return result.position

    assert newest(40) == 19
    assert newest(-7) == 2


@pytest.mark.parametrize("follow", [True, False])
def test_scores_and_positions_kept_between_changes_are_those_computed_afresh(rng, follow):
    """What a step keeps of its trajectories (their scores, positions, route positions) equals what a filter
    restored from its state computes afresh, frame after frame: through direction changes and, following the
    distance, frames that take the newest one's place."""
    n, length = 300, 6
    route = np.cumsum(rng.uniform(0.5, 3.0, n)) if follow else None
    speeds = tuple(signed((0.8, 1.0, 1.25), stopped=not follow))

    def made() -> SequenceFilter:
        return SequenceFilter(length, speeds, 1, 3.0, RingCosts(n, length), 0, 0, route, 30.0 if follow else None,
                              5.0 if follow else 0.0)

    live, q = made(), 0.0
    for t in range(40):
        q += float(rng.choice([0.5, 2.0, 6.0]))  # 0.5 m: within the spacing, the frame replaces the newest
        if t % 7 == 6:
            live.keep_direction(1)
        live.update(rng.normal(size=n).astype(np.float32), rng.integers(0, n, 6), None, None, q if follow else None)
        fresh = made()
        fresh.restore(live.state())
        assert np.array_equal(live.positions(), fresh.positions(), equal_nan=True)
        assert np.array_equal(live.scores(), fresh.scores(), equal_nan=True)
        assert live.best_by_sign() == fresh.best_by_sign()
        assert np.array_equal(live.window(5)[0], fresh.window(5)[0], equal_nan=True)


def _lines(state: dict) -> np.ndarray:
    """(trajectories, window frames) every live trajectory's reference position at each window frame, from a state."""
    times = np.asarray(state["times"], dtype=np.float64)
    return state["anchor_r"][:, None] + state["speed"][:, None] * (times - state["anchor_t"][:, None])


@pytest.mark.parametrize("bound", [4, 60])
def test_the_bounded_filter_online_equals_batch(rng, bound):
    """Following at most ``bound`` trajectories, each as long as anchors fall on it: what a step keeps of a
    trajectory's costs, frame after frame and beyond the window of its first anchor, is its line's costs over the
    window computed afresh; the answer is the lowest mean among them; never more than ``bound`` live."""
    length, n, penalty = 6, 80, 0.3
    frames = synthetic_traverse(rng, 40, n)
    seq = SequenceFilter(length, SPEEDS, 0, penalty, RingCosts(n, length), bound=bound)
    followed_beyond = 0
    for t, (anchors, costs, speeds) in enumerate(frames):
        got = seq.update(costs, anchors, None, speeds)
        state = seq.state()
        window = state["times"]
        lines = np.rint(_lines(state)).astype(np.int64)
        fresh = np.full(lines.shape, penalty)
        for column, tt in enumerate(window):
            if frames[tt][1] is not None:
                inside = (lines[:, column] >= 0) & (lines[:, column] < n)
                fresh[inside, column] = frames[tt][1][lines[inside, column]]
        kept = state["costs"][:, length - len(window):]
        np.testing.assert_allclose(kept, fresh, rtol=1e-6)
        assert len(kept) <= bound
        means = fresh.mean(axis=1)
        best = int(np.argmin(means))
        assert got.score == pytest.approx(means[best], rel=1e-6)
        assert got.position == pytest.approx(_lines(state)[best, -1])
        followed_beyond += int((state["anchor_t"] < window[0]).sum())
    assert followed_beyond > 0  # trajectories outlive their first anchor's window where anchors keep falling on them
    # The true place (map frame 5 + t) is followed.
    assert abs(got.position - (5 + 39)) <= 1


def test_a_bounded_filter_drops_a_trajectory_no_anchor_supported_for_a_window():
    length, n = 5, 50
    seq = SequenceFilter(length, (1.0,), 0, 0.0, RingCosts(n, length), bound=100)
    costs = np.zeros(n, dtype=np.float32)
    seq.update(costs, np.array([10]))
    for t in range(1, 12):
        # Anchors on the line through (0, 10) for three frames, then elsewhere.
        seq.update(costs, np.array([10 + t if t < 3 else 40]))
        lines = np.rint(seq.positions())
        # Supported last at frame 2, the line is dropped once frame 2 leaves the window (frame 2 + length).
        assert (10 + t in lines) == (t < 2 + length)
