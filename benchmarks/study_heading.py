"""How the heading is found, on the four ways of pairing the nuScenes front and rear frames (docs/opposite-view.md).

S1: map from the rear camera, queries from the front one (the paper's setup); S2: map from the front camera,
queries the rear frames played backwards (the road driven the other way); S3: map from the front camera, queries
the rear frames as recorded (a rear camera on a car driving the mapped direction); S4: map from the rear camera,
queries the front frames played backwards (a camera moving away from what it sees, driving the other way). In S1
and S2 the query camera moves towards what it sees, in S3 and S4 away from it. The heading is opposite in all four
and is not declared.

Each variant of the heading vote is run at the recorded 2 Hz and at 1 Hz (every other frame, map and queries,
both halves summed), with the ego poses and with visual odometry: frames whose heading is right, and of them
those where it is sure (at least ``heading.min_confidence``), and Recall@1 at 7.5 m of the look-at points, single
frame and with the sequence filter.

    python benchmarks/study_heading.py [--variants 1,4] [--out benchmarks/results/study_heading.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import tempfile
import warnings
from collections.abc import Callable
from contextlib import nullcontext
from pathlib import Path
from unittest import mock

import numpy as np

from common import RESULTS, print_table, write_json
from lostx.core import Config
from lostx.core.layout.compare import similarities
from lostx.core.match.combined import LayoutComparison, lead, sampled
from study_layout import RATES, SETUPS, TOLERANCE, Study, variant

PAIRINGS = {**SETUPS, "S3": ("front", "rear", False), "S4": ("rear", "front", True)}
"""Map camera, query camera, queries played backwards."""
MOTIONS = {"ego poses": Config(), "visual odometry": variant(motion=dict(source="visual"))}


def _vote_against_own_grids(comparison: LayoutComparison) -> float:
    """The layout's vote as it was: the frame's grid as it lies and turned, both against the map camera's own grids
    in one unshifted pass; which one's best stands further above the rest."""
    same, turned = similarities(list(comparison.views), comparison.maps.rows(sampled(comparison.maps.n)),
                                comparison.weights, 0, comparison.min_cells)
    return float(np.sign(lead(turned) - lead(same)))


VARIANTS: dict[str, tuple[dict, object]] = {
    "half weight (default)": ({}, None),
    "equal weights": ({"layout_vote": 1.0}, None),
    "LoST-X alone": ({"layout_vote": 0.0}, None),
    "equal weights, own grids (before)": ({"layout_vote": 1.0}, _vote_against_own_grids),
    "half weight, own grids": ({}, _vote_against_own_grids),
}
"""The frame's vote is LoST-X's and the layout's weighted mean (``heading.layout_vote`` the layout's weight: half,
equal, none); the layout votes with the scores each heading ranks its answers by (the matcher's), or with its
grid as it lies and turned, both against the map camera's own grids ("own grids"). Each: the heading settings
changed, and the layout's vote in place of the matcher's (None: the matcher's)."""


def run_pairing(config: Config, pairing: str, every: int, study: Study) -> dict[str, int]:
    counts = study.counts(config, PAIRINGS[pairing], every)
    single, sequence = counts["single"], counts["sequence"]
    return {"queries": single["counted"], "single": single["right"], "sequence": sequence["right"],
            "heading": single["opposite"], "sure": single["sure"], "frames": single["frames"],
            "entering": sequence["entering"], "entering right": sequence["entering right"]}


def sixteen_runs(study: Study, changed: Callable[[Config], Config], label: str) -> dict[str, dict[str, dict[str, int]]]:
    """:func:`run_pairing` of every pairing at each rate with each motion source, its configuration ``changed`` from
    the motion source's; keyed "rate, motion", each column said done (after ``label``) as it ends."""
    out = {}
    for rate, every in RATES.items():
        for motion, base in MOTIONS.items():
            out[f"{rate}, {motion}"] = {p: run_pairing(changed(base), p, every, study) for p in PAIRINGS}
            print(f"{label}: {rate}, {motion} done", flush=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", help="comma-separated numbers of the variants to run (1 = the default; all)")
    parser.add_argument("--out", type=Path, default=RESULTS / "study_heading.json")
    args = parser.parse_args()
    names = list(VARIANTS)
    if args.variants:
        names = [names[int(i) - 1] for i in args.variants.split(",")]
    warnings.simplefilter("ignore")
    results: dict[str, dict] = {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        study = Study(Path(tmp))
        for name in names:
            changes, vote = VARIANTS[name]
            patch = mock.patch("lostx.core.match.matcher.layout_vote", vote) if vote is not None else nullcontext()
            with patch:
                results[name] = sixteen_runs(study, lambda base, changes=changes: dataclasses.replace(
                    base, heading=dataclasses.replace(base.heading, **changes)), name)
            for column, out in results[name].items():
                rows.append([name if not any(row[0] == name for row in rows) else "", column,
                             *[f"{o['heading']} ({o['sure']}) / {o['frames']}" for o in out.values()],
                             *[f"{o['single']}/{o['sequence']} of {o['queries']}" for o in out.values()],
                             sum(o["heading"] for o in out.values()),
                             sum(o["single"] + o["sequence"] for o in out.values())])
    print_table("The heading, undeclared: frames right (of them sure) / frames; Recall@1 at 7.5 m, single/sequence",
                ["variant", "frames, motion", *[f"{p} heading" for p in PAIRINGS], *[f"{p} R@1" for p in PAIRINGS],
                 "heading sum", "R@1 sum"], rows)
    write_json(args.out, {"tolerance_m": TOLERANCE, "pairings": PAIRINGS, "variants": results})


if __name__ == "__main__":
    main()
