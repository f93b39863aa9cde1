"""VPR-Bench datasets (Zaffar et al., IJCV 2021): ``ref/``, ``query/`` and ``ground_truth_new.npy``.

VPR-Bench orders the images of each folder by the integer value of the file
stem (``2.jpg`` before ``10.jpg``), and the ground truth indexes those orders,
so this reader orders them the same way; stems that are not integers fall back
to name order (noted). The ground truth file is described in
:func:`lostx.core.groundtruth.load_vprbench`.
"""

from __future__ import annotations

from pathlib import Path

from lostx.core.errors import InputError
from lostx.core.frame import Camera
from lostx.core.groundtruth import GroundTruth, load_vprbench
from lostx.core.images import list_images

from .folder import Traverse

GROUND_TRUTH = "ground_truth_new.npy"


def is_vprbench(folder: str | Path) -> bool:
    folder = Path(folder)
    return (folder / "ref").is_dir() and (folder / "query").is_dir()


def vprbench_traverse(folder: Path, camera: Camera = "front", mirror: bool = False) -> Traverse:
    files = list_images(folder)
    notes = []
    if all(f.stem.isdigit() for f in files):
        files.sort(key=lambda f: int(f.stem))
    else:
        notes.append(f"{folder}: file stems are not all integers; images taken in name order")
    return Traverse(folder.parent.name + "/" + folder.name, files, camera=camera, mirror=mirror, notes=notes)


def vprbench_pair(
    root: str | Path, query_camera: Camera = "front", reference_camera: Camera = "front", mirror_query: bool = False
) -> tuple[Traverse, Traverse, GroundTruth]:
    """(reference, query, ground truth) of a VPR-Bench dataset folder."""
    root = Path(root)
    if not is_vprbench(root):
        raise InputError(f"{root}: not a VPR-Bench dataset (expected ref/ and query/ folders)")
    reference = vprbench_traverse(root / "ref", reference_camera)
    query = vprbench_traverse(root / "query", query_camera, mirror_query)
    gt_path = root / GROUND_TRUTH
    if not gt_path.is_file():
        raise InputError(f"{root}: no {GROUND_TRUTH} (VPR-Bench's ground truth) beside ref/ and query/")
    truth = load_vprbench(gt_path, len(query), len(reference))
    return reference, query, truth
