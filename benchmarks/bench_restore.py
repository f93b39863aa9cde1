"""What carrying a stream's state across a restart costs: its size on disk, and the time to save and restore it.

A service with a journal saves the states of the streams each batch of answers
advanced (lostx.stream.states), so that a restarted service carries on. This
measures that state over thumbnail maps of Nordland's summer traverse (the whole
route, 3,576 frames, and its first 1,000), after the localizer has stepped
through winter frames with the sequence filter on: the packed size (and the
bound lostx.core.budget.state_bytes gives for it), the time to pack it (the
worker, every frame), to complete a batch with it (the journal thread: one file
for the batch, written whole and synced, the folder synced) and the same for a
batch of 8 streams, against writing 8 files of one state each (one fsync each),
and to unpack and restore it (once per stream, at its first frame after a
restart). The journal itself does not grow with it: its records are the answers
as before.

    python benchmarks/bench_restore.py [--frames 60] [--repeat 20] [--quick] [--out benchmarks/results/restore.json]
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
from lostx.core.budget import state_bytes
from lostx.core.config import Config
from lostx.stream.states import SavedState, StateStore, _write_whole, pack, unpack


def measure(refmap: ReferenceMap, frames: list, repeat: int, folder: Path) -> dict:
    localizer = Localizer(refmap)
    for frame in frames:
        localizer.step(frame)
    packed = pack(localizer.state())
    parts = {name: len(pack(part)) for name, part in localizer.state().items()}
    restored = Localizer(refmap)
    store = StateStore(folder)
    seq = iter(range(1, 1 << 30))

    def batch(streams: int) -> None:
        n = next(seq)
        store.complete(n, [SavedState(f"s{k}", n, n, None, packed + bytes([n % 256])) for k in range(streams)])

    def files(streams: int) -> None:  # a file per stream, as before the batch files
        for k in range(streams):
            _write_whole(folder / f"stream{k}.state", packed, True)
        _write_whole(folder / "durable", b"1", True)

    return {
        "map_frames": refmap.n_frames,
        "frames_stepped": len(frames),
        "state_bytes": len(packed),
        "state_bound_bytes": state_bytes(Config(), refmap.n_frames),
        "part_bytes": parts,
        "pack": common.summary(common.time_call(lambda: pack(localizer.state()), repeat)),
        "batch_1": common.summary(common.time_call(lambda: batch(1), repeat)),
        "batch_8": common.summary(common.time_call(lambda: batch(8), repeat)),
        "files_8": common.summary(common.time_call(lambda: files(8), repeat)),
        "restore": common.summary(common.time_call(lambda: restored.restore(unpack(packed)), repeat)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--repeat", type=int, default=20)
    args = common.parse(parser, "restore", quick="10 frames stepped, 3 timed calls")
    if args.quick:
        args.frames, args.repeat = 10, 3
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
            states = Path(tmp) / f"states{size or 'all'}"
            states.mkdir()
            run = measure(ReferenceMap.open(out), winter, args.repeat, states)
            runs.append(run)
            rows.append([run["map_frames"], run["state_bytes"] / 1e3, run["state_bound_bytes"] / 1e3,
                         run["part_bytes"]["filters"] / 1e3, run["pack"]["median_ms"], run["batch_1"]["median_ms"],
                         run["batch_8"]["median_ms"], run["files_8"]["median_ms"], run["restore"]["median_ms"]])
    common.print_table(f"A stream's saved state after {args.frames} Nordland winter frames (medians of {args.repeat})",
                       ["map frames", "state kB", "bound kB", "of it sequence filters kB", "pack ms", "batch of 1 ms",
                        "batch of 8 ms", "8 files ms", "restore ms"], rows)
    common.write_json(args.out, {"frames": args.frames, "repeat": args.repeat, "runs": runs})


if __name__ == "__main__":
    main()
