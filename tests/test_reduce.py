"""Wide keypoint descriptors reduced on a projection learnt from the map: nearest neighbours kept, the map's
storage, verification on the reduced evidence, the same answers on real features."""

from __future__ import annotations

import json

import numpy as np
import pytest
from backbonetools import lostx

from lostx.core import LostDescriber, PlaceMatcher, ReferenceMap, build_map
from lostx.core.backbones import BackboneInfo
from lostx.core.config import Config, VerifyConfig
from lostx.core.describe.keypoints import KeypointEvidence, frame_evidence
from lostx.core.describe.reduce import learn_projection, project_rows, reduced_dims, sample_rows
from lostx.core.maps.mapwriter import MapFrame, MapWriter
from lostx.core.match.verify import verify
from lostx.replay.folder import folder_traverse

D, GRID = 600, (8, 12)


def _cosine(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    return a @ b.T


def test_projection_keeps_the_nearest_neighbours_of_descriptors_near_a_subspace(rng):
    # 960-dim descriptors of 300 places (100 triples of close ones) spanning 40 directions, plus noise in every
    # channel, as large as the places' differences: queries are fresh views of every third place.
    basis = rng.standard_normal((40, 960)) * 10 / np.sqrt(960)
    places = np.repeat(rng.standard_normal((100, 40)), 3, axis=0) + 0.3 * rng.standard_normal((300, 40))
    refs = places @ basis + rng.standard_normal((300, 960))
    truth = np.arange(0, 300, 3)
    queries = (places[truth] + 0.1 * rng.standard_normal((100, 40))) @ basis + rng.standard_normal((100, 960))
    projection = learn_projection(refs, 64)
    assert projection.shape == (960, 64) and projection.dtype == np.float32
    np.testing.assert_allclose(projection.T @ projection, np.eye(64), atol=1e-5)
    whole = _cosine(queries, refs).argmax(axis=1)
    reduced = _cosine(project_rows(queries, projection), project_rows(refs, projection)).argmax(axis=1)
    assert (whole == truth).sum() >= 99 and (reduced == truth).sum() >= (whole == truth).sum()
    assert (reduced == whole).sum() >= 99
    # 64 random directions keep far fewer: the learnt ones are what keeps them.
    random = np.linalg.qr(rng.standard_normal((960, 64)))[0]
    assert (_cosine(queries @ random, refs @ random).argmax(axis=1) == truth).sum() < 90


def test_projection_is_the_same_for_the_same_rows_and_its_signs_are_fixed(rng):
    rows = rng.standard_normal((500, 30))
    a, b = learn_projection(rows, 8), learn_projection(rows.copy(), 8)
    np.testing.assert_array_equal(a, b)
    assert (a[np.abs(a).argmax(axis=0), np.arange(8)] > 0).all()
    assert learn_projection(rows, 50).shape == (30, 30)  # never more dimensions than the features have


def test_which_maps_reduce_and_the_sample_they_learn_from():
    assert reduced_dims(VerifyConfig(), 448) is None and reduced_dims(VerifyConfig(), 512) is None
    assert reduced_dims(VerifyConfig(), 960) == 64
    assert reduced_dims(VerifyConfig(reduce_above=100, reduced_dim=600), 448) is None
    np.testing.assert_array_equal(sample_rows(10, 4), [0, 3, 6, 9])
    assert len(sample_rows(100_000, 8192)) <= 8192 and sample_rows(5, 8192).tolist() == [0, 1, 2, 3, 4]


def _scene(rng, dense: bool) -> tuple[np.ndarray, np.ndarray]:
    n = GRID[0] * GRID[1]
    mix = rng.standard_normal((D, 24)) @ rng.standard_normal((24, n))  # features of few directions
    features = mix if dense else np.maximum(mix, 0.0)
    return features.astype(np.float32).reshape(D, *GRID), rng.integers(0, 3, GRID).astype(np.uint8)


def _map(path, frames, verify_config: VerifyConfig) -> ReferenceMap:
    info = BackboneInfo("synthetic", "none", "0" * 32, D, GRID, ("a", "b", "c"), {})
    with MapWriter(path, "lost", {"camera": "front"}, backbone=info, index=False, verify=verify_config) as writer:
        for i, (features, labels) in enumerate(frames):
            writer.add(MapFrame(f"{i:03d}.png", np.ones(3 * D, np.float32), frame_evidence(features, labels)))
        writer.commit()
    return ReferenceMap.open(path)


@pytest.mark.parametrize("dense", [True, False])
def test_a_wide_map_keeps_reduced_descriptors_and_verifies_like_the_whole_one(tmp_path, rng, dense):
    base, labels = _scene(rng, dense)
    frames = [(base + 0.2 * rng.standard_normal(base.shape).astype(np.float32), labels) for _ in range(6)]
    frames += [_scene(rng, dense) for _ in range(4)]  # other places
    whole = _map(tmp_path / "whole", frames, VerifyConfig(reduce_above=4096))
    reduced = _map(tmp_path / "reduced", frames, VerifyConfig())
    manifests = [json.loads((m.path / "manifest.json").read_text()) for m in (whole, reduced)]
    assert [m["version"] for m in manifests] == [1, 2]  # a map kept whole still opens in older readers
    assert manifests[1]["arrays"]["projection"]["shape"] == [D, 64]
    assert manifests[1]["arrays"]["slot_projected"]["dtype"] == "<f2"
    assert "slot_values" not in manifests[1]["arrays"] and "slot_values" in manifests[0]["arrays"]

    def per_frame(manifest: dict) -> float:
        return sum(e["bytes"] for k, e in manifest["arrays"].items() if k != "projection") / 10

    assert per_frame(manifests[1]) < per_frame(manifests[0]) / (8 if dense else 2)

    query = frame_evidence(base + 0.2 * rng.standard_normal(base.shape).astype(np.float32), labels)
    candidates = np.arange(10)
    exact = verify(whole.query_evidence(query), whole.evidence(candidates), np.full(10, 0.5))
    approx = verify(reduced.query_evidence(query), reduced.evidence(candidates), np.full(10, 0.5))
    np.testing.assert_array_equal(approx.n_consistent, exact.n_consistent)
    # Features of few directions (dense) lose almost nothing: each correspondence's similarity (before the
    # density test) stays within 0.02 on average; the rectified ones (sparse) span more directions.
    pairs = [verify(m.query_evidence(query), m.evidence(candidates), np.full(10, 0.5), density="off")
             for m in (whole, reduced)]
    gap = max(np.abs(pairs[1].correspondences(c).similarity - pairs[0].correspondences(c).similarity).mean()
              for c in candidates)
    assert gap < (0.02 if dense else 0.1), gap
    assert set(np.argsort(approx.scores)[:6]) == set(range(6))  # the six views of the place verify best
    assert set(np.argsort(exact.scores)[:6]) == set(range(6))


def test_reduced_evidence_needs_a_projected_query(tmp_path, rng, capsys):
    refmap = _map(tmp_path / "m", [_scene(rng, True) for _ in range(3)], VerifyConfig())
    ran = lostx(capsys, "map", "info", refmap.path)
    assert ran.code == 0 and "format version 2" in ran.out
    assert "600 channels on a 8x12 grid, keypoint descriptors reduced to 64 dimensions" in ran.out
    query = frame_evidence(*_scene(rng, True))
    with pytest.raises(ValueError, match="query's keypoint descriptors have 600 dimensions, the references' 64"):
        verify(query, refmap.evidence([0, 1]), np.full(2, 0.5))
    with pytest.raises(ValueError, match="no sparse form"):
        KeypointEvidence.stack([refmap.query_evidence(query)])


def test_mosaic_features_reduced_find_the_same_night_frames(robotcar, mosaic, tmp_path):
    # MOSAIC's 448 channels are kept whole by default; reduced to 64 here, its RobotCar answers stay the same.
    describer = LostDescriber(mosaic)
    found = {}
    for name, settings in (("whole", VerifyConfig()), ("reduced", VerifyConfig(reduce_above=256))):
        build_map(folder_traverse(robotcar / "day"), tmp_path / name, Config(verify=settings), describer,
                  progress=False)
        refmap = ReferenceMap.open(tmp_path / name)
        assert (refmap.projection is not None) == (name == "reduced")
        matcher = PlaceMatcher(refmap, backbone=mosaic)
        found[name] = [int(matcher.match(frame.image).same.candidates[0]) for frame in folder_traverse(robotcar / "night")]
    assert found["reduced"] == found["whole"]
    assert sum(best == k for k, best in enumerate(found["whole"])) == 6
