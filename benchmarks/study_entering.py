"""Entering the map: what the sequence filter's switch cost does where the queries start off the map
(docs/opposite-view.md).

In S3 and S4 (study_heading's pairings: the cameras the other way round) the first six to eight queries have no
counterpart within 7.5 m: the vehicle drives towards the mapped stretch from outside it. Its best matches there
are look-alikes, and a trajectory through them leads the window when the vehicle enters the map. In S1 and S2 the
queries leave the map at the end instead. Each switch cost (``sequence.switch_cost``, J) is run on the sixteen
runs (S1 to S4, 2 Hz and 1 Hz, the ego poses and visual odometry): Recall@1 at 7.5 m with the sequence filter per
pairing, of it the queries within 10 frames of entering the map (S3 and S4), and the single frame's for
comparison (the switch cost does not change it).

    python benchmarks/study_entering.py [--costs 2 3 4 6 8 inf] [--out benchmarks/results/study_entering.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import math
import tempfile
import warnings
from pathlib import Path

from common import RESULTS, print_table, write_json
from lostx.core import Config
from study_heading import PAIRINGS, sixteen_runs
from study_layout import ENTERED, TOLERANCE, Study


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--costs", type=float, nargs="+", default=[2.0, 3.0, 4.0, 6.0, 8.0, math.inf],
                        help="switch costs J (inf: each trajectory's own mean over the window)")
    parser.add_argument("--out", type=Path, default=RESULTS / "study_entering.json")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    default = Config().sequence.switch_cost
    results: dict[str, dict] = {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        study = Study(Path(tmp))
        for cost in args.costs:
            name = f"switch cost {cost:g}" + (" (default)" if cost == default else "")
            runs_out = sixteen_runs(study, lambda base, cost=cost: dataclasses.replace(
                base, sequence=dataclasses.replace(base.sequence, switch_cost=cost)), name)
            results[name] = runs_out
            every_run = [o for run in runs_out.values() for o in run.values()]
            rows.append([name, *[sum(run[p]["sequence"] for run in runs_out.values()) for p in PAIRINGS],
                         sum(o["sequence"] for o in every_run), sum(o["single"] for o in every_run),
                         sum(o["queries"] for o in every_run),
                         f"{sum(o['entering right'] for o in every_run)}/{sum(o['entering'] for o in every_run)}",
                         runs_out["2 Hz, ego poses"]["S1"]["sequence"], runs_out["2 Hz, ego poses"]["S2"]["sequence"]])
    print_table("Recall@1 at 7.5 m with the sequence filter over the sixteen runs: per pairing, all, the single frame "
                "(all), of queries; the first 10 queries on the map where the run starts off it; S1 and S2 at 2 Hz with "
                "the ego poses", ["switch cost", *[f"{p} sequence" for p in PAIRINGS], "sequence", "single", "of",
                                  "entering", "S1 2 Hz", "S2 2 Hz"], rows)
    write_json(args.out, {"tolerance_m": TOLERANCE, "entered": ENTERED, "pairings": PAIRINGS, "results": results})


if __name__ == "__main__":
    main()
