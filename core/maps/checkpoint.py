"""A map build's checkpoint: the chunks of frames already described, kept beside the map folder.

``.NAME.build/`` next to the map folder ``NAME`` holds ``checkpoint.json`` (what is being built:
the frames, the kind of map, every setting and the backbone) and one ``chunk-START-STOP.npz`` per
run of described frames, each written whole or not at all. A build that stops (Ctrl-C, a crash,
a bad frame) leaves it; the same build started again describes only the frames no chunk holds,
and the map it writes is the one an uninterrupted build writes. A checkpoint of another build
(other frames or settings) is discarded. The folder is removed once the map is committed.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

from .mapwriter import MapChunk

CHECKPOINT_FILE = "checkpoint.json"
_CHUNK = re.compile(r"^chunk-(\d+)-(\d+)\.npz$")


class BuildCheckpoint:
    """The checkpoint of the build of map folder ``out``; ``key`` identifies the build (None: a build that
    cannot be resumed, whose frames cannot be identified)."""

    def __init__(self, out: str | Path, key: str | None) -> None:
        out = Path(out)
        self.folder = out.parent / f".{out.name}.build"
        self.key = key

    def resume(self) -> list[tuple[int, int, Path]]:
        """(start, stop, file) of each chunk an earlier run of this build saved, in frame order."""
        if not self.folder.is_dir():
            return []
        try:
            stored = json.loads((self.folder / CHECKPOINT_FILE).read_text()).get("key")
        except (OSError, ValueError, AttributeError):
            stored = None
        if self.key is None or stored != self.key:
            self.remove()
            return []
        chunks = []
        for path in self.folder.iterdir():
            match = _CHUNK.match(path.name)
            if match:
                chunks.append((int(match.group(1)), int(match.group(2)), path))
        return sorted(chunks)

    def save(self, chunk: MapChunk) -> Path:
        """Keep a chunk (atomically) and say where."""
        if not (self.folder / CHECKPOINT_FILE).is_file():
            self.folder.mkdir(parents=True, exist_ok=True)
            tmp = self.folder / f".{CHECKPOINT_FILE}.{os.getpid()}"
            tmp.write_text(json.dumps({"key": self.key}))
            os.replace(tmp, self.folder / CHECKPOINT_FILE)
        path = self.folder / f"chunk-{chunk.start:010d}-{chunk.stop:010d}.npz"
        chunk.save(path)
        return path

    def remove(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)


def missing_ranges(saved: list[tuple[int, int, Path]], n_frames: int | None) -> list[tuple[int, int | None]]:
    """The frame ranges [start, stop) no saved chunk covers (stop None: to the end of a traverse of
    unknown length)."""
    out: list[tuple[int, int | None]] = []
    at = 0
    for start, stop, _ in saved:
        if start > at:
            out.append((at, start))
        at = max(at, stop)
    if n_frames is None or at < n_frames:
        out.append((at, n_frames))
    return out
