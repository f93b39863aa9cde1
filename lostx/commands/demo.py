"""``lostx demo``: the day/night example on the RobotCar pair in ../shared/data."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lostx.core.config import Config
from lostx.core.errors import InputError, MapError
from lostx.core.localizer import Localizer
from lostx.core.backbone import load_backbone
from lostx.core.build import build_map
from lostx.core.describe import LostDescriber
from lostx.core.paths import cache_dir, data_dir
from lostx.core.refmap import ReferenceMap
from lostx.options import add_backbone_options, add_viewer_options, close_viewer, config_from_args, viewer_sink_from_args
from lostx.replay.folder import folder_traverse


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("demo", help="map the RobotCar day frames, localize the night frames")
    parser.add_argument("--data", type=Path, help="folder holding robotcar-daynight/ (default ../shared/data)")
    parser.add_argument("--workdir", type=Path, help="where the demo keeps its map (default ~/.cache/lostx/demo)")
    parser.add_argument("--rebuild", action="store_true", help="rebuild the map even if one is there")
    add_backbone_options(parser)
    add_viewer_options(parser)
    parser.set_defaults(run=run)


def demo_map(day: Path, out: Path, config: Config, rebuild: bool) -> ReferenceMap:
    """The day map, reused when one built by the same backbone from the same folder is there."""
    backbone = load_backbone(config.backbone)
    if not rebuild and (out / "manifest.json").is_file():
        try:
            refmap = ReferenceMap.open(out)
            refmap.check_backbone(backbone.info)
            if refmap.manifest.get("image_root") == str(day.resolve()):
                print(f"reusing the map in {out}")
                return refmap
        except MapError:
            pass
    traverse = folder_traverse(day)
    summary = build_map(traverse, out, config, LostDescriber(backbone, config.lost),
                        {"camera": "front", "image_root": str(day.resolve())}, overwrite=True, total=len(traverse))
    print(f"built {summary.path}: {summary.n_frames} frames, {summary.bytes_per_frame / 1e3:.1f} kB per frame")
    return ReferenceMap.open(out)


def run(args: argparse.Namespace) -> int:
    config = config_from_args(args)
    data = (args.data or data_dir()) / "robotcar-daynight"
    if not (data / "day").is_dir() or not (data / "night").is_dir():
        raise InputError(f"demo data not found: {data} should hold day/ and night/ (pass --data or set LOSTX_DATA)")
    workdir = args.workdir or cache_dir() / "demo"
    refmap = demo_map(data / "day", workdir / f"robotcar-day-{config.backbone.name}", config, args.rebuild)
    localizer = Localizer(refmap, config)
    sink = viewer_sink_from_args(args, refmap)
    night = folder_traverse(data / "night")
    print(f"\n{'query':>14s}  {'match':>12s}  {'truth':>5s}  {'score':>8s}  {'conf':>5s}  {'corr':>4s}")
    found = []
    try:
        for frame in night:
            est = localizer.step(frame)
            if sink is not None:
                sink(frame, est)
            found.append(est.match_index)
            mark = "exact" if est.match_index == frame.id else ("+-1" if abs(est.match_index - frame.id) == 1 else "wrong")
            print(f"{frame.name:>14s}  {est.match_name:>12s}  {frame.id:>5d}  {est.score:8.4f}  "
                  f"{est.confidence:5.2f}  {est.candidates[0].correspondences:4d}  {mark}")
    finally:
        close_viewer(sink)
    truth = np.arange(len(found))
    exact = int((np.asarray(found) == truth).sum())
    near = int((np.abs(np.asarray(found) - truth) <= 1).sum())
    print(f"\nnight -> day, single frame: {exact}/{len(found)} exact, {near}/{len(found)} within one frame "
          f"(the authors' LoST-X on the same frames: 6 exact, 8 within one)")
    return 0
