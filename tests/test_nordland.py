"""The sequence filter and tracker at scale: 3576 Nordland frames, summer map, winter queries (thumbnails).

Peer to beat, measured on exactly these frames (issue 3): batch pySeqSLAM (sequence length 10,
speeds 0.8-1.2, contrast enhancement) reaches, at a tolerance of 1 frame, recall at 100 % precision
0.32, max F1 0.61, Recall@1 0.53 (0.38, 0.69, 0.59 with its uint8 wrap-around fixed). It is non-causal;
these runs are causal.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lostx.core import Config, Localizer, ReferenceMap, build_map
from lostx.core.config import SearchConfig, SequenceConfig, TrackerConfig
from lostx.evaluation.groundtruth import index_aligned
from lostx.evaluation.metrics import evaluate
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.replay.folder import folder_traverse

MODES = {
    "single": Config(sequence=SequenceConfig(enabled=False)),
    "sequence": Config(tracker=TrackerConfig(enabled=False)),
    "sequence+tracker": Config(),
    # As on a city-scale map: through the map's approximate index, costs looked up where the filter looks.
    "sequence+tracker, index": Config(search=SearchConfig(index="on"), sequence=SequenceConfig(costs="looked-up")),
}

# (tolerance in frames) -> (recall at 100 % precision, max F1, Recall@1), measured with the defaults.
MEASURED = {
    "single": {0: (0.003, 0.073, 0.045), 1: (0.004, 0.076, 0.047), 2: (0.004, 0.079, 0.049)},
    "sequence": {0: (0.512, 0.872, 0.83), 1: (0.611, 0.884, 0.844), 2: (0.695, 0.892, 0.852)},
    "sequence+tracker": {0: (0.522, 0.875, 0.867), 1: (0.643, 0.889, 0.889), 2: (0.698, 0.903, 0.903)},
    "sequence+tracker, index": {0: (0.517, 0.9, 0.875), 1: (0.734, 0.915, 0.904), 2: (0.765, 0.921, 0.918)},
}


@pytest.fixture(scope="module")
def summer_map(tmp_path_factory, nordland) -> ReferenceMap:
    out = tmp_path_factory.mktemp("nordland") / "summer"
    build_map(folder_traverse(nordland / "summer"), out, describer=ThumbnailDescriber(), progress=False)
    return ReferenceMap.open(out)


@pytest.fixture(scope="module")
def runs(summer_map, nordland) -> dict[str, list]:
    winter = list(folder_traverse(nordland / "winter"))
    runs = {}
    for name, cfg in MODES.items():
        localizer = Localizer(summer_map, cfg)
        runs[name] = [localizer.step(f) for f in winter]
    return runs


def figures(estimates: list) -> dict[int, tuple[float, float, float]]:
    pred = np.array([e.match_index for e in estimates])
    conf = np.array([e.confidence for e in estimates])
    out = {}
    for gt in index_aligned(len(pred), 3576, [0, 1, 2]):
        ev = evaluate(pred, conf, gt, candidates=pred[:, None], higher_is_better=True)
        out[int(gt.tolerance)] = (round(ev.recall_at_100p, 3), round(ev.max_f1, 3), round(ev.recall_at_n[1], 3))
    return out


@pytest.mark.parametrize("mode", list(MODES))
def test_measured_figures(runs, mode):
    assert figures(runs[mode]) == MEASURED[mode]


def test_sequence_filter_beats_batch_seqslam_clearly():
    r100, f1, r1 = MEASURED["sequence+tracker"][1]
    assert r100 > 0.38 + 0.15 and f1 > 0.69 + 0.15 and r1 > 0.59 + 0.25


def test_localized_answers_are_right(runs):
    for mode in ("sequence", "sequence+tracker", "sequence+tracker, index"):
        estimates = runs[mode]
        localized = [e for e in estimates if e.state == "localized"]
        wrong = [e for e in localized if abs(e.match_index - e.frame_id) > 1]
        assert wrong == []
        # Measured: 2078 (sequence), 2105 (with the tracker) and 2307 (through the index, costs looked up) of
        # 3576, never below the 2069 (57.9 %) that the margins' ranks among the map's wrong answers gave with the
        # tracker, nor the 56.5 % of a fixed threshold tuned on this data.
        assert len(localized) >= 2069


def test_warm_up_is_reported(runs):
    estimates = runs["sequence+tracker"]
    length = Config().sequence.length
    assert [e.window for e in estimates[:length + 1]] == list(range(1, length + 1)) + [length]
    assert all(e.warming_up and e.state == "not_localized" and e.confidence == 0.0 for e in estimates[: length - 1])
    assert not estimates[length].warming_up


GAP = (1500, 1700)  # summer places removed from the map


@pytest.fixture(scope="module", params=["off", "on"], ids=["every frame", "index and costs looked up"])
def gap_run(request, tmp_path_factory, nordland) -> tuple[np.ndarray, list, bool]:
    """With costs for every map frame, and as on a city-scale map: through the index, costs looked up."""
    summer = folder_traverse(nordland / "summer")
    kept = [i for i in range(len(summer)) if not GAP[0] <= i < GAP[1]]
    out = tmp_path_factory.mktemp("gap") / "map"
    build_map(summer.subset(kept), out, describer=ThumbnailDescriber(), progress=False)
    config = MODES["sequence+tracker, index" if request.param == "on" else "sequence+tracker"]
    localizer = Localizer(ReferenceMap.open(out), config)
    winter = folder_traverse(nordland / "winter")
    queries = np.arange(1200, 2000)
    return queries, [localizer.step(dataclasses.replace(winter.frame(q), id=int(q))) for q in queries], \
        request.param == "on"


def test_leaving_the_map(gap_run):
    queries, estimates, looked_up = gap_run
    # Map index of each query's true place (-1 inside the removed stretch).
    truth = np.where(queries < GAP[0], queries, np.where(queries >= GAP[1], queries - (GAP[1] - GAP[0]), -1))
    localized = np.array([e.state == "localized" for e in estimates])
    pred = np.array([e.match_index for e in estimates])
    inside = truth < 0
    assert inside.sum() == 200
    # Measured: not localized for all 200 frames of the stretch, no confident answer there at all.
    assert not localized[inside].any()
    assert max(e.confidence for e, i in zip(estimates, inside) if i) < Config().decision.min_confidence
    # ... and localized again 18 frames after the stretch (the window is 20 frames long; 19 looked up), correctly.
    after = np.flatnonzero(~inside & (queries >= GAP[1]) & localized)
    assert after[0] - np.flatnonzero(queries == GAP[1])[0] == (19 if looked_up else 18)
    # Measured: every localized answer exact, 389 of them with costs for every map frame, 394 looked up.
    errors = np.abs(pred - truth)[localized]
    assert localized.sum() == (394 if looked_up else 389) and errors.max() == 0
