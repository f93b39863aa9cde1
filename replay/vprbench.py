"""VPR-Bench datasets (Zaffar et al., IJCV 2021): ``ref/``, ``query/`` and ``ground_truth_new.npy``.

VPR-Bench orders the images of each folder by the integer value of the file
stem (``2.jpg`` before ``10.jpg``), and the ground truth indexes those orders,
so this reader orders them the same way; stems that are not integers fall back
to name order (noted). The ground truth file is described in
:func:`lostx.evaluation.groundtruth.load_vprbench`;
the pair is opened by :func:`lostx.evaluation.datasets.vprbench_pair`.
"""

from __future__ import annotations

from pathlib import Path

from lostx.core.frame import Camera
from lostx.core.images import list_images

from .folder import Traverse
from .store import ImageFiles

GROUND_TRUTH = "ground_truth_new.npy"


def is_vprbench(folder: str | Path) -> bool:
    folder = Path(folder)
    return (folder / "ref").is_dir() and (folder / "query").is_dir()


def vprbench_traverse(folder: Path, camera: Camera | None = None, mirror: bool = False) -> Traverse:
    files = list_images(folder)
    notes = []
    if all(f.stem.isdigit() for f in files):
        files.sort(key=lambda f: int(f.stem))
    else:
        notes.append(f"{folder}: file stems are not all integers; images taken in name order")
    return Traverse(folder.parent.name + "/" + folder.name, ImageFiles(files), camera=camera, mirror=mirror,
                    notes=notes)
