"""``lostx map build`` and ``lostx map info``."""

from __future__ import annotations

import argparse
import shlex
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.options import (
    add_config_options,
    add_source_options,
    config_from_args,
    print_notes,
    source_options_from_args,
    whole_number,
)

if TYPE_CHECKING:
    from lostx.core.build import BuildInterrupted


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("map", help="build or inspect reference maps")
    verbs = parser.add_subparsers(dest="verb", metavar="VERB", required=True)

    build = verbs.add_parser("build", help="build a reference map from a traverse (images, a bag, a video, ...)")
    build.add_argument("source", type=Path, help="the traverse: a folder of images (name order), a RobotCar "
                       "folder, a ROS 2 bag (.mcap), a video, a nuScenes scene (see docs/datasets.md)")
    build.add_argument("--out", type=Path, required=True, help="map folder to write")
    build.add_argument("--positions", type=Path, help="CSV of positions (file,x,y or lat,lon; optional timestamp); "
                       "RobotCar: the INS CSV")
    build.add_argument("--camera", choices=["front", "rear"],
                       help="camera direction of the traverse (default: as the source declares it, else front)")
    build.add_argument("--descriptor", choices=["lost", "thumbnail"], default="lost",
                       help="LoST-X (default) or SeqSLAM thumbnails (no network)")
    build.add_argument("--overwrite", action="store_true", help="replace an existing map at --out")
    build.add_argument("--quiet", action="store_true", help="no progress bar")
    build.add_argument("--ray", nargs="?", const="", metavar="ADDRESS",
                       help="describe the frames on a Ray cluster: ADDRESS as ray.init takes it (auto, "
                       "ray://HOST:10001); without one, a Ray instance started on this machine for the build "
                       "(needs pip install \"lostx[ray]\"; see docs/scale.md)")
    build.add_argument("--ray-workers", type=whole_number(1), metavar="N",
                       help="describers at once on Ray (default: one per GPU, else one per backbone.threads CPUs)")
    add_source_options(build)
    add_config_options(build, matching=False)
    build.set_defaults(run=run_build)

    info = verbs.add_parser("info", help="describe a map")
    info.add_argument("map", type=Path)
    info.add_argument("--verify", action="store_true",
                      help="also check every file's checksum and measure the index's Recall@10 against exact search")
    info.add_argument("--samples", type=whole_number(1), metavar="N",
                      help="map frames --verify searches for (default 500, evenly spaced)")
    info.add_argument("--config", type=Path, help="TOML file of settings: the [search] breadth and shortlist --verify "
                      "measures (see docs/config.md)")
    info.set_defaults(run=run_info)


def run_build(args: argparse.Namespace) -> int:
    from lostx.core.backbones import load_backbone
    from lostx.core.build import BuildInterrupted, build_map
    from lostx.core.describe.describer import LostDescriber
    from lostx.core.describe.thumbnail import ThumbnailDescriber
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.core.outputs import check_output_folder
    from lostx.replay.dataset import open_traverse

    config = config_from_args(args)
    check_output_folder(args.out, "--out")
    traverse = open_traverse(args.source, args.format, args.camera, args.positions,
                             options=source_options_from_args(args))
    print_notes(traverse.notes)
    camera = traverse.camera or "front"
    if args.descriptor == "lost":
        describer: LostDescriber | ThumbnailDescriber = LostDescriber(load_backbone(config.backbone), config.lost)
    else:
        describer = ThumbnailDescriber()
    metadata = {"camera": camera, "image_root": str(traverse.root.resolve())}
    cluster = None
    if args.ray is not None:
        # Ray is imported only here: a build without --ray runs as it always did, Ray installed or not.
        from lostx.cluster.raybuild import RayDescribers

        cluster = RayDescribers(args.ray or None, args.ray_workers)
    try:
        summary = build_map(traverse, args.out, config, describer, metadata, overwrite=args.overwrite,
                            total=len(traverse), progress=not args.quiet, label=f"describing {traverse.root.name}",
                            cluster=cluster)
    except BuildInterrupted as stop:
        raise KeyboardInterrupt(resume_line(stop, len(traverse), args.command_line)) from None
    print(
        f"built {summary.path}: {summary.n_frames} frames ({args.descriptor}) in {summary.seconds:.1f} s, "
        f"{summary.bytes / 1e6:.2f} MB ({summary.bytes_per_frame / 1e3:.1f} kB per frame)"
    )
    if args.descriptor == "lost":
        print(_layout_line(ReferenceMap.open(summary.path), traverse))
    return 0


def resume_line(stop: BuildInterrupted, total: int, command_line: list[str]) -> str:
    """What an interrupted build kept, and the command that resumes it (the same one again)."""
    if not stop.kept:
        return "no frame was described yet, so there is nothing to resume from"
    return (f"{stop.kept} of {total} frames described are kept (in {stop.checkpoint}); to resume, run the same "
            f"command again: {shlex.join(command_line)}")


def _layout_line(refmap, traverse) -> str:  # noqa: ANN001 (ReferenceMap, Traverse: imported lazily)
    """What the map knows of its places' layout, and why not where it has none."""
    if refmap.layout_settings is not None:
        motion = "odometry" if traverse.odometry is not None else "visual odometry"
        ends = ("as its camera and as the other end of its stretch see it" if refmap.stores_other_ends
                else "as its camera saw it")
        return (f"layout     on: a grid of {refmap.layout_settings.cell:g} m cells per frame, {ends}, "
                f"motion from {motion}")
    if traverse.geometry is None:
        return ("layout     off: the frames carry no camera geometry (put a camera.toml beside them or give "
                "--camera-file; see docs/datasets.md), so a view from the other end is matched by LoST-X alone")
    return "layout     off (switched off, or the model has no road class)"


def run_info(args: argparse.Namespace) -> int:
    from lostx.core.config import load_config
    from lostx.core.maps.refmap import ReferenceMap

    refmap = ReferenceMap.open(args.map, verify_checksums=args.verify)
    m = refmap.manifest
    backbone = m.get("backbone") or {}
    print(f"map        {refmap.path}")
    print(f"kind       {refmap.kind}, format version {m['version']}, built {m['created']}")
    print(f"frames     {refmap.n_frames} ({refmap.camera} camera) from {m.get('image_root', '?')}")
    if backbone:
        print(f"backbone   {backbone['name']} ({backbone['model_file']}, md5 {backbone['model_md5']})")
        reduced = (f", keypoint descriptors reduced to {refmap.projection.shape[1]} dimensions"
                   if refmap.kind == "lost" and refmap.projection is not None else "")
        print(f"features   {backbone['feature_dim']} channels on a {backbone['grid'][0]}x{backbone['grid'][1]} grid"
              f"{reduced}")
    if m.get("classes"):
        print("classes    " + "; ".join(f"{k}: {', '.join(v)}" for k, v in m["classes"].items()))
    looks = m.get("input")
    if looks:
        sizes = " to ".join(dict.fromkeys(f"{w} x {h}" for w, h in zip(looks["width"], looks["height"])))
        grey = looks["greyscale"]
        kind = "" if grey is None else (" greyscale" if grey >= 0.5 else " colour")
        print(f"input      {sizes}{kind} images, mean brightness {looks['brightness'][0]:.0f} to "
              f"{looks['brightness'][1]:.0f} of 255")
    print(f"positions  {'yes' if refmap.positions is not None else 'no'}")
    print(f"size       {refmap.nbytes / 1e6:.2f} MB ({refmap.nbytes / refmap.n_frames / 1e3:.1f} kB per frame)")
    print("scale      " + scale_line(refmap.nbytes / refmap.n_frames, load_config(args.config)))
    index = m.get("index")
    if index:
        print(f"index      {index['metric']} HNSW over 8-bit codes ({index['neighbours']} neighbours), "
              f"{index['bytes'] / 1e6:.2f} MB")
    else:
        print("index      none (built by an older lostx: every search compares every frame)")
    if args.verify:
        print("checksums  all files match")
        if index:
            _print_recall(refmap, args)
    return 0


SCALE_FRAMES = 1_000_000
"""The map size ``lostx map info`` sizes a map up to: a city at a frame every 2 m."""


def scale_line(bytes_per_frame: float, config) -> str:  # noqa: ANN001 (Config: imported lazily)
    """What a map of :data:`SCALE_FRAMES` frames at ``bytes_per_frame`` would take: on disk (the map's arrays are
    memory-mapped, read as they are matched), one stream's working memory and its saved state with ``config``
    (:mod:`lostx.core.budget`)."""
    from lostx.core.budget import format_bytes, state_bytes, stream_bytes

    n = SCALE_FRAMES
    state = state_bytes(config, n)
    saved = f"its saved state {format_bytes(state)}" if state else "no saved state (costs looked up)"
    return (f"a map of {n:,} such frames: {format_bytes(bytes_per_frame * n)} on disk, memory-mapped; one stream's "
            f"working memory {format_bytes(stream_bytes(config, n))}, {saved}")


def _print_recall(refmap, args: argparse.Namespace) -> None:  # noqa: ANN001 (ReferenceMap: imported lazily)
    from tqdm import tqdm

    from lostx.core.config import load_config
    from lostx.core.match.indexcheck import SAMPLES, index_recall

    search = load_config(args.config).search
    samples = args.samples or SAMPLES
    with tqdm(total=min(samples, refmap.n_frames), desc="index against exact", unit="query", leave=False) as bar:
        r = index_recall(refmap, search, samples=samples, progress=bar.update)
    print(f"recall     Recall@{r.k} {r.recall:.3f} against exact search (worst frame {r.worst:.2f}) on {r.queries} "
          f"map frames, breadth {r.breadth}, shortlist {r.shortlist}; {r.index_ms:.2f} ms per index search, "
          f"{r.exact_ms:.2f} ms exact")
