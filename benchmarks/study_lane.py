"""The road driven the other way one lane over: the sideways reach of the layout's comparison against a query that
drives a lane to the side of the map's route (docs/opposite-view.md).

A car driving a mapped road the other way drives another lane: where traffic keeps right, the map's route lies
a lane to its left; where it keeps left, to its right. The nuScenes scene has one drive, so its front and rear
frames share their lane; here each query's layout grid is gathered as by a camera ``--lane`` metres to its side
(every point the frames saw, counted where it lands from there; nothing resampled), and LoST-X sees the frames as
they are (the appearance of one lane over is not simulated). Each sideways reach (``layout.across_shift``) is
run on study_heading's sixteen runs (S1 to S4, 2 Hz and 1 Hz, the ego poses and visual odometry) with the queries
in the map's lane, a lane to the right and a lane to the left; Recall@1 at 7.5 m summed, single frame and
sequence, and the frames whose heading is right.

    python benchmarks/study_lane.py [--shifts 2 4 6] [--lane 3.5] [--out benchmarks/results/study_lane.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import dataclasses
import tempfile
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from unittest import mock

import numpy as np

from common import RESULTS, print_table, write_json
from lostx.core.layout.describer import LiveLayout, Placed
from lostx.core.layout.grid import Gathering
from lostx.core.motion.pose import compose
from study_heading import PAIRINGS, sixteen_runs
from study_layout import TOLERANCE, Study


@contextmanager
def one_lane_over(metres: float) -> Iterator[None]:
    """Every query grid gathered as by a camera ``metres`` to its left (negative: to its right): each live frame's
    gathering made to stand there, wherever it is then gathered (on a thread or in the comparison process)."""
    add = LiveLayout.add

    def beside(self: LiveLayout, frame: Placed) -> Gathering:
        gathering = add(self, frame)
        return dataclasses.replace(gathering, current=compose(gathering.current, np.array([0.0, metres, 0.0])))

    with mock.patch.object(LiveLayout, "add", beside):
        yield


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--shifts", type=float, nargs="+", default=[2.0, 4.0, 6.0], help="sideways reaches, metres")
    parser.add_argument("--lane", type=float, default=3.5, help="a lane's width, metres")
    parser.add_argument("--out", type=Path, default=RESULTS / "study_lane.json")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    lanes = {"the map's lane": 0.0, "a lane to the right": -args.lane, "a lane to the left": args.lane}
    results: dict[str, dict] = {}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        study = Study(Path(tmp))
        for shift in args.shifts:
            name = f"sideways shift +-{shift:g} m"
            results[name] = {}
            for lane, metres in lanes.items():
                with one_lane_over(metres):
                    runs = sixteen_runs(study, lambda base, shift=shift: dataclasses.replace(
                        base, layout=dataclasses.replace(base.layout, across_shift=shift)), f"{name}, {lane}")
                results[name][lane] = runs
                every_run = [o for run in runs.values() for o in run.values()]
                rows.append([name if not any(row[0] == name for row in rows) else "", lane,
                             sum(o["single"] for o in every_run), sum(o["sequence"] for o in every_run),
                             sum(o["queries"] for o in every_run), sum(o["heading"] for o in every_run),
                             sum(o["frames"] for o in every_run),
                             *[sum(run[p]["single"] + run[p]["sequence"] for run in runs.values()) for p in PAIRINGS]])
    print_table("Queries a lane over: Recall@1 at 7.5 m over the sixteen runs (single, sequence, of queries), "
                "heading right (of frames), and single + sequence per pairing",
                ["sideways reach", "queries", "single", "sequence", "of", "heading", "of frames",
                 *[f"{p} R@1" for p in PAIRINGS]], rows)
    write_json(args.out, {"tolerance_m": TOLERANCE, "lane_m": args.lane, "pairings": PAIRINGS, "results": results})


if __name__ == "__main__":
    main()
