"""How many answers are `localized`, and how many of them are right, on Nordland (summer map, winter queries,
thumbnails, right within 1 frame): the whole route, and maps of short stretches of it (docs/metrics.md).

Each stretch is a map of its own, built from the summer frames of the stretch and calibrated on them alone;
its winter frames are the queries. Sequence filter and tracker (the default) and single frame. Also the
reliability of the confidence: answers binned by confidence, with the share of each bin that is right.

    python benchmarks/study_calibration.py [--lengths 100 200] [--stretches 8] [--full] [--out FILE]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import tempfile
from itertools import pairwise
from pathlib import Path

import numpy as np

from common import parse, print_table, write_json
from lostx.core import Config, Localizer, ReferenceMap, build_map
from lostx.core.config import SequenceConfig
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.core.paths import data_dir
from lostx.replay.folder import folder_traverse

NORDLAND = data_dir() / "nordland-64x32"
MODES = {"sequence + tracker": Config(), "single frame": Config(sequence=SequenceConfig(enabled=False))}
BINS = (0.0, 0.5, 0.9, 0.99, 0.999, 1.0)
TOLERANCE = 1
NEAR = 5
"""Also counted: answers within this many frames, the places the confidence's margin does not tell apart
(``sequence.exclusion``)."""


def run(frames: range, workdir: Path) -> dict[str, dict]:
    """Map of the summer frames ``frames``, their winter frames as queries; per mode the counts."""
    summer, winter = folder_traverse(NORDLAND / "summer"), folder_traverse(NORDLAND / "winter")
    out = workdir / f"map-{frames.start}-{frames.stop}"
    build_map(summer.subset(frames), out, describer=ThumbnailDescriber(), progress=False)
    refmap = ReferenceMap.open(out)
    results = {}
    for mode, config in MODES.items():
        localizer = Localizer(refmap, config)
        estimates = [localizer.step(dataclasses.replace(winter.frame(q), id=k)) for k, q in enumerate(frames)]
        error = np.array([abs(e.match_index - e.frame_id) for e in estimates])
        right, near = error <= TOLERANCE, error <= NEAR
        localized = np.array([e.state == "localized" for e in estimates])
        confidence = np.array([e.confidence for e in estimates])
        bins = np.clip(np.searchsorted(BINS, confidence, side="right") - 1, 0, len(BINS) - 2)
        results[mode] = {
            "queries": len(estimates), "right": int(right.sum()), "localized": int(localized.sum()),
            "localized_right": int((localized & right).sum()), "localized_near": int((localized & near).sum()),
            "bins": [[int((bins == b).sum()), int(((bins == b) & right).sum()), int(((bins == b) & near).sum())]
                     for b in range(len(BINS) - 1)],
        }
    return results


HEADER = ["stretch", "frames", "mode", "right", "localized", "localized right", f"within {NEAR}"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lengths", type=int, nargs="*", default=[100, 200])
    parser.add_argument("--stretches", type=int, default=8, help="stretches of each length, spread over the route")
    parser.add_argument("--full", action="store_true", help="also the whole route (3576 frames)")
    args = parse(parser, "study_calibration", "one map of 100 frames")
    if args.quick:
        args.lengths, args.stretches, args.full = [100], 1, False
    total = len(folder_traverse(NORDLAND / "summer"))
    spans = [range(int(s), int(s) + n) for n in args.lengths
             for s in np.linspace(0, total - n, args.stretches).astype(int)]
    if args.full:
        spans.append(range(total))
    rows, payload = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for frames in spans:
            results = run(frames, Path(tmp))
            payload.append({"start": frames.start, "frames": len(frames), "modes": results})
            for mode, r in results.items():
                rows.append([f"{frames.start}-{frames.stop - 1}", len(frames), mode, r["right"], r["localized"],
                             r["localized_right"], r["localized_near"]])
                print_table("", HEADER, rows[-1:])
    print_table(f"Nordland, localized answers per map (right within {TOLERANCE} frame)", HEADER, rows)
    summary = []
    for n in sorted({p["frames"] for p in payload}):
        for mode in MODES:
            runs = [p["modes"][mode] for p in payload if p["frames"] == n]
            bins = np.sum([r["bins"] for r in runs], axis=0)
            summary.append([n, len(runs), mode, sum(r["queries"] for r in runs), sum(r["localized"] for r in runs),
                            sum(r["localized_right"] for r in runs), sum(r["localized_near"] for r in runs),
                            *[f"{b[1]} ({b[2]}) / {b[0]}" for b in bins]])
    print_table(f"Totals by map length; reliability: right (within {NEAR} frames) / answers per confidence bin",
                ["frames", "maps", "mode", "queries", "localized", "right", f"within {NEAR}", *[
                    f"[{lo:g},{hi:g})" for lo, hi in pairwise(BINS)]], summary)
    write_json(args.out, {"tolerance_frames": TOLERANCE, "near_frames": NEAR, "bins": list(BINS), "maps": payload})


if __name__ == "__main__":
    main()
