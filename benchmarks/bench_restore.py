"""What carrying a stream's state across a restart costs: its size on disk, and the time to save and restore it.

A service with a journal saves each stream's localizer state after every batch
of answers (lostx.stream.states), so that a restarted service carries on. This
measures that state over thumbnail maps of Nordland's summer traverse (the whole
route, 3,576 frames, and its first 1,000), after the localizer has stepped
through winter frames with the sequence filter on: the packed size, the time
to pack it (the worker, every frame), to write it whole with fsync (the journal
thread, once per stream and batch), and to unpack and restore it (once per
stream, at its first frame after a restart). The journal itself does not grow
with it: its records are the answers as before; the ``states/`` folder holds one
state per live stream.

    python benchmarks/bench_restore.py [--frames 60] [--repeat 20] [--out benchmarks/results/restore.json]
"""

from __future__ import annotations

import common  # noqa: F401  (first: it limits numpy's BLAS threads before numpy loads)

import argparse
import tempfile
from pathlib import Path

from lostx.core.build import build_map
from lostx.core.describe.thumbnail import ThumbnailDescriber
from lostx.core.localizer import Localizer
from lostx.core.maps.refmap import ReferenceMap
from lostx.core.paths import data_dir
from lostx.replay.folder import folder_traverse
from lostx.stream.states import _write_whole, pack, unpack


def measure(refmap: ReferenceMap, frames: list, repeat: int, folder: Path) -> dict:
    localizer = Localizer(refmap)
    for frame in frames:
        localizer.step(frame)
    packed = pack(localizer.state())
    parts = {name: len(pack(part)) for name, part in localizer.state().items()}
    target = folder / "stream.state"
    restored = Localizer(refmap)
    return {
        "map_frames": refmap.n_frames,
        "frames_stepped": len(frames),
        "state_bytes": len(packed),
        "part_bytes": parts,
        "pack": common.summary(common.time_call(lambda: pack(localizer.state()), repeat)),
        "write_fsync": common.summary(common.time_call(lambda: _write_whole(target, packed, True), repeat)),
        "restore": common.summary(common.time_call(lambda: restored.restore(unpack(packed)), repeat)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeat", type=int, default=20)
    parser.add_argument("--out", type=Path, default=common.RESULTS / "restore.json")
    args = parser.parse_args()
    nordland = data_dir() / "nordland-64x32"
    winter = list(folder_traverse(nordland / "winter"))[: args.frames]
    rows, runs = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for size in (1000, None):
            summer = folder_traverse(nordland / "summer")
            if size is not None:
                summer = summer.subset(range(size))
            out = Path(tmp) / f"summer{size or 'all'}"
            build_map(summer, out, describer=ThumbnailDescriber(), metadata={"camera": "front"}, progress=False)
            run = measure(ReferenceMap.open(out), winter, args.repeat, Path(tmp))
            runs.append(run)
            rows.append([run["map_frames"], run["state_bytes"] / 1e3, run["part_bytes"]["sequence"] / 1e3,
                         run["pack"]["median_ms"], run["write_fsync"]["median_ms"], run["restore"]["median_ms"]])
    common.print_table(f"A stream's saved state after {args.frames} Nordland winter frames (medians of {args.repeat})",
                       ["map frames", "state kB", "of it sequence kB", "pack ms", "write+fsync ms", "restore ms"],
                       rows)
    common.write_json(args.out, {"frames": args.frames, "repeat": args.repeat, "runs": runs})


if __name__ == "__main__":
    main()
