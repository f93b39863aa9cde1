"""A reference traverse and a query traverse, and the ground truth that says which matches are right.

Pair formats (``format=`` or recognised from the folders):

- ``vprbench``: one folder with ``ref/``, ``query/`` and ``ground_truth_new.npy``
  (given as the reference; there is no separate query folder);
- ``robotcar``: RobotCar traverse folders, a camera chosen for each side;
- ``folder``: folders of images in name order with positions CSVs: ground truth
  by distance in metres; likewise ``bag``, ``video`` and ``nuscenes`` sources (and
  pairs of different formats), by their positions;
- ``pairs``: two folders of images in name order (or two videos) where the same
  index is the same place (Nordland, the RobotCar day/night sample): ground truth
  in frames.

Two plain image folders (or videos) are ``folder`` when both have positions,
``pairs`` when neither has.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from lostx.core.errors import InputError
from lostx.core.frame import Camera
from lostx.replay.dataset import FORMATS, POSITIONS_FILE, SourceOptions, detect_format, open_traverse
from lostx.replay.folder import Traverse
from lostx.replay.positions import latlon_to_local
from lostx.replay.subsample import subsample_by_distance
from lostx.replay.vprbench import GROUND_TRUTH, is_vprbench, vprbench_traverse

from .groundtruth import GroundTruth, Unit, from_indices, from_positions, load_vprbench

ALIGNABLE = ("folder", "video")
"""Formats read without positions as index-aligned pairs when neither side has any."""


@dataclass
class DatasetPair:
    """A reference traverse (the map) and a query traverse, and how to tell which matches are right."""

    reference: Traverse
    query: Traverse
    format: str
    """The format read ('robotcar', 'pairs', ...; 'robotcar+folder' when the two sides differ)."""
    aligned: bool = False
    """Same index (or, after subsampling, same original frame number) = same place."""
    listed: GroundTruth | None = None
    """The dataset's own ground truth lists (VPR-Bench), indexed like the two traverses."""

    @property
    def has_positions(self) -> bool:
        return self.reference.positions is not None and self.query.positions is not None

    @property
    def default_unit(self) -> Unit:
        """Metres when both sides have positions, else frames."""
        return "m" if self.has_positions else "frames"

    @property
    def notes(self) -> list[str]:
        return [*(f"reference: {n}" for n in self.reference.notes), *(f"query: {n}" for n in self.query.notes)]

    def ground_truth(self, tolerances: float | Sequence[float], unit: Unit | None = None) -> list[GroundTruth]:
        """One ground truth per tolerance: a radius in metres, or a number of frames.

        Frames: for index-aligned pairs, ``|r - q| <= tolerance`` on the original frame
        numbers; for VPR-Bench, the listed references widened by ``tolerance`` frames on
        each side (0 = the file as is). Metres: positions within the radius.
        """
        unit = unit or self.default_unit
        if unit == "m":
            if not self.has_positions:
                missing = [s.name for s in (self.reference, self.query) if s.positions is None]
                raise InputError(
                    f"ground truth in metres needs positions for both traverses; none for {', '.join(missing)} "
                    f"(give a positions CSV, or use frame tolerances on an index-aligned pair)"
                )
            ref_xy, query_xy = shared_positions(self.reference, self.query)
            return from_positions(query_xy, ref_xy, tolerances, source="positions")
        if unit != "frames":
            raise InputError(f"tolerance unit must be 'frames' or 'm', got {unit!r}")
        if self.listed is not None:
            return [self.listed.widened(_whole_frames(t)) for t in _tolerance_list(tolerances)]
        if self.aligned:
            ref_places = _places(self.reference)
            query_places = _places(self.query)
            return from_indices(query_places, len(self.reference), tolerances, ref_places, source="index-aligned")
        raise InputError(
            f"frame tolerances need an index-aligned pair (--format pairs) or a dataset with its own ground truth; "
            f"{self.reference.name} and {self.query.name} are neither: use a radius in metres"
        )

    def subsampled(self, spacing: float) -> "DatasetPair":
        """Both traverses with one frame kept every ``spacing`` metres travelled."""
        if self.listed is not None:
            raise InputError("a VPR-Bench ground truth indexes the full image sets; it cannot be subsampled")
        return replace(
            self,
            reference=subsample_by_distance(self.reference, spacing),
            query=subsample_by_distance(self.query, spacing),
        )


def open_pair(
    reference: str | Path,
    query: str | Path | None = None,
    format: str | None = None,
    *,
    reference_camera: Camera | None = None,
    query_camera: Camera | None = None,
    reference_positions: str | Path | None = None,
    query_positions: str | Path | None = None,
    mirror_query: bool = False,
    spacing: float | None = None,
    options: SourceOptions | None = None,
    reverse_query: bool = False,
    undeclared: bool = False,
) -> DatasetPair:
    """Read a reference/query pair in any supported format (see the module docstring).

    A camera left as None is what the source declares (RobotCar: front). ``options``
    apply to each side whose format uses them (a bag's topics, a nuScenes scene, every
    N-th frame...). ``spacing`` subsamples both traverses by distance travelled (metres);
    ``reverse_query`` then runs the query backwards (the route driven the other way).
    ``undeclared`` drops the query camera's declared direction: the heading is then found from
    the images alone.
    The result's :meth:`DatasetPair.ground_truth` gives the true sets at any tolerances.
    """
    if format is not None and format not in FORMATS:
        raise InputError(f"unknown dataset format {format!r}; expected one of {', '.join(FORMATS)}")
    reference = Path(reference)
    if format == "vprbench" or (format is None and query is None):
        if query is not None:
            raise InputError(f"a VPR-Bench dataset holds ref/ and query/ in one folder; give only {reference}")
        if not is_vprbench(reference):
            raise InputError(
                f"{reference}: no query folder given, and this is not a VPR-Bench dataset (ref/, query/, "
                f"ground_truth_new.npy)"
            )
        if options is not None and options != SourceOptions():
            raise InputError(f"{reference}: a VPR-Bench dataset is read whole; source options do not apply")
        ref, qry, listed = vprbench_pair(reference, query_camera, reference_camera or "front", mirror_query)
        pair = DatasetPair(ref, qry, "vprbench", listed=listed)
        return _finish(pair, spacing, reverse_query, undeclared)
    if query is None:
        raise InputError(f"no query folder given for the {format} reference {reference}")
    query = Path(query)

    if format == "pairs":  # index-aligned: folders read as plain folders, recordings as what they are
        kinds = tuple("pairs" if side.is_dir() else detect_format(side) for side in (reference, query))
    else:
        kinds = (format, format) if format else (detect_format(reference), detect_format(query))
    for kind, side in zip(kinds, (reference, query)):
        if kind == "vprbench":
            raise InputError(f"{side} is a VPR-Bench dataset (ref/ and query/ inside); give it alone as the reference")
    options = options or SourceOptions()
    misplaced = sorted(set(options.misplaced(kinds[0])) & set(options.misplaced(kinds[1])))
    if misplaced:
        raise InputError(f"{', '.join(misplaced)} {'does' if len(misplaced) == 1 else 'do'} not apply to a "
                         f"{kinds[0]} or {kinds[1]} source")
    ref = open_traverse(reference, kinds[0], reference_camera, reference_positions, options=options.only_for(kinds[0]))
    qry = open_traverse(query, kinds[1], query_camera, query_positions, mirror_query, options.only_for(kinds[1]))

    unplaced = format is None and set(kinds) <= set(ALIGNABLE)  # formats that may come without positions
    if format == "pairs" or (unplaced and not _any_positions(ref, qry)):
        check_aligned(ref, qry)
        pair = DatasetPair(ref, qry, "pairs", aligned=True)
    else:
        if unplaced and not (ref.positions is not None and qry.positions is not None):
            without = reference if ref.positions is None else query
            raise InputError(
                f"{without} has no positions but the other traverse has: give positions for both (a "
                f"{POSITIONS_FILE} or a CSV), or use --format pairs for index-aligned traverses"
            )
        name = kinds[0] if kinds[0] == kinds[1] else f"{kinds[0]}+{kinds[1]}"
        pair = DatasetPair(ref, qry, name)
    return _finish(pair, spacing, reverse_query, undeclared)


def _finish(pair: DatasetPair, spacing: float | None, reverse_query: bool, undeclared: bool) -> DatasetPair:
    if spacing:
        pair = pair.subsampled(spacing)
    if reverse_query:
        if pair.listed is not None:
            raise InputError("a VPR-Bench ground truth lists the queries in their order; they cannot be reversed")
        pair = replace(pair, query=pair.query.reversed())
    if undeclared:
        pair = replace(pair, query=replace(pair.query, camera=None))
    return pair


def check_aligned(reference: Traverse, query: Traverse) -> None:
    """Index-aligned pairs must have one query per reference frame."""
    if len(reference) != len(query):
        shorter, longer = (reference, query) if len(reference) < len(query) else (query, reference)
        extra = longer.names[len(shorter)]
        raise InputError(
            f"index-aligned pair of different lengths: {reference.root} has {len(reference)} images, "
            f"{query.root} has {len(query)}; index {len(shorter)} ({extra}) has no counterpart"
        )


def shared_positions(reference: Traverse, query: Traverse) -> tuple[np.ndarray, np.ndarray]:
    """Both traverses' positions in one metric frame.

    Positions read as metres (x,y or UTM easting/northing) are used as they are.
    Positions read as latitude/longitude are re-projected about the reference's
    first position, since each traverse was projected about its own first fix.
    """
    assert reference.positions is not None and query.positions is not None
    if (reference.geo is None) != (query.geo is None):
        geo_side = reference if reference.geo is not None else query
        raise InputError(
            f"{geo_side.name} has latitude/longitude positions but the other traverse has metres; "
            f"give both in the same form"
        )
    if reference.geo is None:
        return reference.positions, query.positions
    assert query.geo is not None
    origin = (float(reference.geo[0, 0]), float(reference.geo[0, 1]))
    return (
        latlon_to_local(reference.geo[:, 0], reference.geo[:, 1], origin),
        latlon_to_local(query.geo[:, 0], query.geo[:, 1], origin),
    )


def _any_positions(*traverses: Traverse) -> bool:
    return any(t.positions is not None for t in traverses)


def _places(traverse: Traverse) -> np.ndarray:
    return traverse.source_indices if traverse.source_indices is not None else np.arange(len(traverse))


def _tolerance_list(tolerances: float | Sequence[float]) -> list[float]:
    return [float(tolerances)] if np.isscalar(tolerances) else [float(t) for t in tolerances]  # type: ignore[union-attr]


def _whole_frames(tolerance: float) -> int:
    if tolerance < 0 or tolerance != int(tolerance):
        raise InputError(f"frame tolerance must be a whole number >= 0, got {tolerance}")
    return int(tolerance)


def vprbench_pair(
    root: str | Path, query_camera: Camera | None = None, reference_camera: Camera | None = "front",
    mirror_query: bool = False
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
