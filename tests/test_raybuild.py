"""Building a map on Ray (``lostx map build --ray``) gives the single-process build's map, byte for byte."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lostx.cli import main
from lostx.core.maps.mapwriter import EVIDENCE

ray = pytest.importorskip("ray", reason="the Ray build needs the ray extra: pip install \"lostx[ray]\"")


@pytest.fixture(scope="module")
def local_ray():
    """A Ray instance on this machine with two CPUs: two workers describe at once."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


class ChunkStarts:
    """Wraps RayDescribers.describe to record where each chunk that came back from the workers starts."""

    def __init__(self) -> None:
        self.starts: list[int] = []

    def wrap(self, describe):
        def recording(describer, frames, ranges, config, thumbnail, on_chunk):
            def arrived(chunk, backbone):
                self.starts.append(chunk.start)
                on_chunk(chunk, backbone)

            return describe(describer, frames, ranges, config, thumbnail, arrived)

        return recording


@pytest.fixture(scope="module")
def chunk_starts() -> ChunkStarts:
    return ChunkStarts()


@pytest.fixture(scope="module")
def maps(tmp_path_factory, robotcar, local_ray, chunk_starts) -> tuple[Path, Path]:
    from lostx.cluster.raybuild import RayDescribers

    patch = pytest.MonkeyPatch()
    patch.setattr(RayDescribers, "describe", chunk_starts.wrap(RayDescribers.describe))
    out = tmp_path_factory.mktemp("raybuild")
    one, cluster = out / "one", out / "ray"
    assert main(["map", "build", str(robotcar / "day"), "--out", str(one), "--quiet", "--threads", "1"]) == 0
    # One CPU per worker: two workers, each given five of the ten frames (and their window's neighbours).
    assert main(["map", "build", str(robotcar / "day"), "--out", str(cluster), "--quiet", "--threads", "1",
                 "--ray", "--ray-workers", "2"]) == 0
    patch.undo()
    return one, cluster


def _manifest(path: Path) -> dict:
    return json.loads((path / "manifest.json").read_text())


def test_ray_build_gives_the_same_descriptors_and_evidence_byte_for_byte(maps):
    one, cluster = maps
    a, b = _manifest(one), _manifest(cluster)
    assert a["n_frames"] == b["n_frames"] == 10 and a["frames"] == b["frames"]
    for name in ("descriptors", "stats_mean", "stats_std", "appearance", *EVIDENCE):
        assert a["arrays"][name]["sha256"] == b["arrays"][name]["sha256"], name
        assert (one / f"{name}.npy").read_bytes() == (cluster / f"{name}.npy").read_bytes(), name
    assert a["arrays"].keys() == b["arrays"].keys()
    # The index is built from the same descriptors in the same order: the same file.
    assert a["index"] == b["index"]
    drop = ("created", "arrays", "index")
    assert {k: v for k, v in a.items() if k not in drop} == {k: v for k, v in b.items() if k not in drop}


def test_the_frames_were_described_by_two_workers_in_two_tasks(maps, chunk_starts):
    assert sorted(chunk_starts.starts) == [0, 5]


def test_ray_build_leaves_no_checkpoint_and_the_maps_answer_alike(maps):
    one, cluster = maps
    assert not (cluster.parent / f".{cluster.name}.build").exists() and not (one.parent / f".{one.name}.build").exists()
    d1 = np.load(one / "descriptors.npy")
    d2 = np.load(cluster / "descriptors.npy")
    assert d1.dtype == np.float16 and d1.shape[0] == 10 and np.array_equal(d1, d2)


def test_a_build_without_ray_does_not_import_it(robotcar, tmp_path):
    code = ("import sys; from lostx.cli import main; "
            f"main(['map', 'build', {str(robotcar / 'day')!r}, '--out', {str(tmp_path / 'm')!r}, '--quiet', "
            "'--descriptor', 'thumbnail']); print('ray' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "False"
