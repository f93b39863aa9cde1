"""Reference maps: exact storage, atomic writes, memory mapping, and clear errors on damaged maps."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from lostx.core.backbones import BackboneInfo, Quantisation
from lostx.core.errors import MapError
from lostx.core.describe.keypoints import frame_evidence
from lostx.core.maps.mapwriter import MapFrame, MapWriter
from lostx.core.maps.refmap import ReferenceMap

SCALE = 0.05


def _info(quantised: bool) -> BackboneInfo:
    return BackboneInfo(
        name="synthetic", model_file="none", model_md5="0" * 32, feature_dim=16, grid=(4, 6),
        class_names=("other", "road"), default_classes={"road": ("road",)},
        feature_quantisation=Quantisation(SCALE, 0) if quantised else None,
    )


def _frames(rng, n: int, quantised: bool) -> list[MapFrame]:
    frames = []
    for i in range(n):
        q = rng.integers(0, 256, (16, 4, 6)) * (rng.random((16, 4, 6)) > 0.7)
        features = (q.astype(np.float32) - 0) * np.float32(SCALE) if quantised else (rng.random((16, 4, 6)) * (q > 0)).astype(np.float32)
        labels = rng.integers(0, 2, (4, 6)).astype(np.uint8)
        frames.append(MapFrame(f"{i:04d}.png", rng.random(32).astype(np.float32), frame_evidence(features, labels),
                               position=(float(i), 2.0 * i), timestamp=0.1 * i))
    return frames


def _write(path, frames, quantised=True, **kwargs) -> ReferenceMap:
    with MapWriter(path, "lost", {"camera": "front"}, backbone=_info(quantised), **kwargs) as writer:
        for frame in frames:
            writer.add(frame)
        writer.commit()
    return ReferenceMap.open(path)


@pytest.mark.parametrize("quantised", [True, False])
def test_evidence_round_trip(tmp_path, rng, quantised):
    frames = _frames(rng, 5, quantised)
    refmap = _write(tmp_path / "map", frames, quantised)
    order = [3, 0, 4]
    got = refmap.evidence(order)
    for c, index in enumerate(order):
        want = frames[index].evidence
        np.testing.assert_array_equal(got.keypoints[c], want.keypoints[0])
        np.testing.assert_array_equal(got.labels[c], want.labels[0])
        rows = slice(*np.searchsorted(got.slot_keys, [c * 24, (c + 1) * 24]))
        np.testing.assert_array_equal(got.slot_keys[rows] - c * 24, want.slot_keys)
        dense = got.dense_slots()[rows]
        if quantised:  # uint8 storage is exact
            np.testing.assert_array_equal(dense, want.dense_slots())
        else:  # float16 storage
            np.testing.assert_allclose(dense, want.dense_slots(), rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(refmap.positions[4], (4.0, 8.0))
    assert refmap.names == [f.name for f in frames]
    assert isinstance(refmap._arrays["slot_values"], np.memmap)


def test_descriptors_are_normalised_with_stored_statistics(tmp_path, rng):
    frames = _frames(rng, 6, True)
    refmap = _write(tmp_path / "map", frames)
    np.testing.assert_allclose(np.linalg.norm(refmap.descriptors, axis=1), 1.0, atol=2e-3)
    raw = np.stack([f.descriptor for f in frames])
    unit = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    np.testing.assert_allclose(refmap.stats.mean, unit.mean(axis=0), rtol=1e-5)


def test_an_interrupted_build_leaves_no_map(tmp_path, rng):
    frames = _frames(rng, 3, True)
    with pytest.raises(RuntimeError):
        with MapWriter(tmp_path / "map", "lost", {}, backbone=_info(True)) as writer:
            writer.add(frames[0])
            raise RuntimeError("the camera fell off")
    assert os.listdir(tmp_path) == []


def test_existing_map_is_replaced_only_on_request(tmp_path, rng):
    _write(tmp_path / "map", _frames(rng, 3, True))
    with pytest.raises(MapError, match="already exists; pass --overwrite"):
        _write(tmp_path / "map", _frames(rng, 2, True))
    assert ReferenceMap.open(tmp_path / "map").n_frames == 3
    assert _write(tmp_path / "map", _frames(rng, 2, True), overwrite=True).n_frames == 2
    assert sorted(os.listdir(tmp_path)) == ["map"]


def test_truncated_file_is_named(tmp_path, rng):
    _write(tmp_path / "map", _frames(rng, 3, True))
    target = tmp_path / "map" / "slot_values.npy"
    target.write_bytes(target.read_bytes()[:-10])
    with pytest.raises(MapError, match=r"slot_values.npy is truncated or altered"):
        ReferenceMap.open(tmp_path / "map")


def test_altered_file_fails_checksum(tmp_path, rng):
    _write(tmp_path / "map", _frames(rng, 3, True))
    target = tmp_path / "map" / "labels.npy"
    data = bytearray(target.read_bytes())
    data[-1] ^= 0xFF
    target.write_bytes(bytes(data))
    ReferenceMap.open(tmp_path / "map")  # same size: only the checksum can tell
    with pytest.raises(MapError, match="labels.npy fails its checksum"):
        ReferenceMap.open(tmp_path / "map", verify_checksums=True)


def test_incomplete_and_foreign_folders_are_refused(tmp_path, rng):
    (tmp_path / "half").mkdir()
    (tmp_path / "half" / "descriptors.npy").write_bytes(b"x")
    with pytest.raises(MapError, match="no manifest.json"):
        ReferenceMap.open(tmp_path / "half")
    _write(tmp_path / "map", _frames(rng, 2, True))
    manifest = json.loads((tmp_path / "map" / "manifest.json").read_text())
    manifest["version"] = 99
    (tmp_path / "map" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(MapError, match="format version 99.*rebuild"):
        ReferenceMap.open(tmp_path / "map")
    with pytest.raises(MapError, match="not a folder"):
        ReferenceMap.open(tmp_path / "nothing")


def test_map_refuses_another_backbone(tmp_path, rng):
    refmap = _write(tmp_path / "map", _frames(rng, 2, True))
    other = _info(True)
    refmap.check_backbone(other)
    stranger = BackboneInfo(**{**other.__dict__, "model_md5": "f" * 32})
    with pytest.raises(MapError, match="built with backbone synthetic .* query backbone is synthetic"):
        refmap.check_backbone(stranger)
