"""What a localizer's settings cost in memory and on disk, known before any work is done.

The reference map is memory-mapped (its pages are the operating system's to keep
or drop) and the network is shared by every stream, so what grows with the
settings is each stream's sequence filter: its window of costs, its
trajectories and the working copies an update makes of them. :func:`stream_bytes`
is the one model of that memory and :func:`state_bytes` of the saved state it
packs into; change them together with the filter. :func:`check_memory` refuses,
in one line, settings whose memory would exceed what the machine has available,
naming the setting, what it would need and the largest value that fits.

The figures are upper bounds (every frame spawning trajectories at every anchor
and speed); measured on Nordland's 3,576-frame thumbnail map with the default
20-frame window, a stream peaked at 8 MB (the bound: 12 MB) and its saved state
took 0.8 MB (the bound: 4.3 MB).
"""

from __future__ import annotations

import dataclasses
import os
import resource
from typing import Callable

from .config import Config, looks_up_costs
from .errors import InputError

COST = 8
"""Bytes of a trajectory's cost at one window frame in memory (float64)."""
PACKED_COST = 4
"""The same packed in a saved state (float32: the costs are computed in float32)."""
WINDOW_COST = 4
"""Bytes of one map frame's cost at one window frame (float32), where every map frame's cost is computed."""
REFERENCE_STATISTICS = 3 * 8
"""Bytes per map frame of its running cost statistics (count, sum, sum of squares)."""
TRAJECTORY = 6 * 8
"""Bytes per trajectory besides its costs: anchor frame, progress, position, route position, speed, latest support."""
FILTERS = 7
"""Sequence filters per stream: each heading's over its combined answers, and each cue's own (LoST-X's and the
layout's under each heading, appearance's), which its weight is earned against (lostx.core.route.agreement)."""
WORKING_COPIES = 2
"""Copies of a filter's trajectory costs an update holds besides the filter's own (the window slid into a new
array; the prefix sums of the scores)."""
FRAME_SCRATCH = 16 * 8
"""Bytes per map frame of one frame's map-wide arrays (its scores, their contrast normalisation's sums and
neighbourhoods), where every map frame's cost is computed."""
THREAD_STACK = 8 << 20
"""Bytes an inference thread reserves for its stack (Linux's default; little of it is used)."""


def trajectories(config: Config, n_frames: int) -> int:
    """The most live trajectories one sequence filter holds: every frame of the window spawning one at each of its
    anchors (its verified candidates and its lowest costs) at each speed searched; where costs are looked up, the
    ``hypotheses`` it keeps and one frame's new ones before it keeps them."""
    seq = config.sequence
    speeds = max(_signed(seq.speeds) + 1, _signed(seq.acquire_speeds), _signed(seq.distance_ratios))
    if looks_up_costs(seq, n_frames):
        return seq.hypotheses + (config.verify.top_k + seq.nearest) * speeds
    return seq.length * (config.verify.top_k + seq.anchors) * speeds


def stream_bytes(config: Config, n_frames: int) -> int:
    """Peak memory of one stream's localizer beyond the shared map and network: its sequence filters, each with at
    most :func:`trajectories` trajectories of one cost per window frame (with the working copies of one update), each
    map frame's running cost statistics, and where every map frame's cost is computed, the window's costs of every map
    frame and one frame's map-wide scratch. The filter counts whether or not it answers: measuring the map's
    calibration runs it."""
    length, paths = config.sequence.length, trajectories(config, n_frames)
    per_filter = paths * (length * COST + TRAJECTORY)
    total = FILTERS * per_filter + WORKING_COPIES * paths * length * COST
    if looks_up_costs(config.sequence, n_frames):
        total += FILTERS * n_frames * REFERENCE_STATISTICS
    else:
        total += FILTERS * n_frames * (length * WINDOW_COST + REFERENCE_STATISTICS) + n_frames * FRAME_SCRATCH
    return total


def state_bytes(config: Config, n_frames: int) -> int:
    """The most bytes one stream's saved state takes (:meth:`lostx.core.localizer.Localizer.state`, packed): what
    :func:`stream_bytes` counts but the working copies, costs as float32. 0 where a state is not saved (costs looked
    up on a very large map)."""
    if looks_up_costs(config.sequence, n_frames):
        return 0
    length, paths = config.sequence.length, trajectories(config, n_frames)
    per_filter = paths * (length * PACKED_COST + TRAJECTORY) + n_frames * (length * WINDOW_COST + REFERENCE_STATISTICS)
    return FILTERS * per_filter


def threads_bytes(config: Config) -> int:
    """Memory the network's CPU threads reserve: one stack each."""
    return config.backbone.threads * THREAD_STACK


def needed_bytes(config: Config, n_frames: int, streams: int = 1) -> int:
    """Memory these settings would need at most with ``streams`` streams over a map of ``n_frames``."""
    return streams * stream_bytes(config, n_frames) + threads_bytes(config)


def available_bytes() -> int:
    """Memory the machine can give now without swapping: ``MemAvailable`` (Linux), else the physical memory; within
    what is left of the process's address-space limit where one is set (``ulimit -v``)."""
    info = proc_status("/proc/meminfo")
    available = info.get("MemAvailable")
    if available is None:
        available = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit != resource.RLIM_INFINITY:
        available = min(available, max(0, limit - proc_status("/proc/self/status").get("VmSize", 0)))
    return available


def proc_status(path: str) -> dict[str, int]:
    """The ``Name: value kB`` lines of a /proc file, in bytes (empty where there is none)."""
    out: dict[str, int] = {}
    try:
        with open(path) as handle:
            for line in handle:
                name, _, value = line.partition(":")
                parts = value.split()
                if len(parts) == 2 and parts[1] == "kB" and parts[0].isdigit():
                    out[name] = int(parts[0]) * 1024
    except OSError:
        pass
    return out


def check_memory(config: Config, n_frames: int, streams: int = 1, budget: int | None = None,
                 streams_setting: str = "[stream] max_streams") -> None:
    """Refuse, with one :class:`InputError` line, settings whose memory (:func:`needed_bytes`) would exceed
    ``budget`` (default :func:`available_bytes`): it names the first of the window, the number of streams and the
    threads whose reduction alone would fit, what the settings would need and the largest value that fits (or, where
    none would, the map)."""
    budget = available_bytes() if budget is None else budget
    need = needed_bytes(config, n_frames, streams)
    if need <= budget:
        return
    seq = config.sequence
    what = f"would need {format_bytes(need)} (at most, {streams} stream{'s' * (streams != 1)} over a map of " \
           f"{n_frames} frames), more than the {format_bytes(budget)} of memory available"

    def with_length(length: int) -> Config:
        return _replace(config, "sequence", length=length)

    def with_threads(threads: int) -> Config:
        return _replace(config, "backbone", threads=threads)

    length = _largest(lambda v: needed_bytes(with_length(v), n_frames, streams) <= budget, seq.length)
    if length:
        raise InputError(f"[sequence] length (--window) {seq.length} {what}: the largest window that fits is "
                         f"{length} frames")
    most = _largest(lambda v: needed_bytes(config, n_frames, v) <= budget, streams)
    if most:
        raise InputError(f"{streams_setting} {streams} {what}: at most {most} stream{'s' * (most != 1)} fit")
    threads = _largest(lambda v: needed_bytes(with_threads(v), n_frames, streams) <= budget, config.backbone.threads)
    if threads:
        raise InputError(f"[backbone] threads (--threads) {config.backbone.threads} {what}: at most {threads} fit")
    frames = _largest(lambda v: needed_bytes(config, v, streams) <= budget, n_frames)
    fits = f"the largest map that fits these settings has {frames} frames" if frames else "no map fits them"
    raise InputError(f"the map of {n_frames} frames {what}: {fits}")


def format_bytes(n: float) -> str:
    """A size in the unit that reads best (kB, MB, GB, TB, PB, EB; powers of 1000)."""
    units = ("B", "kB", "MB", "GB", "TB", "PB", "EB")
    for unit in units:
        if n < 999.5 or unit == units[-1]:
            return f"{n:.0f} {unit}" if unit in ("B", units[-1]) else f"{n:.3g} {unit}"
        n /= 1000
    raise AssertionError("unreachable")


def _signed(magnitudes: tuple[float, ...]) -> int:
    return 2 * len({float(m) for m in magnitudes if m > 0})


def _largest(fits: Callable[[int], bool], below: int) -> int:
    """The largest value in [1, below) that ``fits`` (monotone: what fits, fits smaller too); 0 where none does."""
    low, high = 0, below
    while high - low > 1:
        middle = (low + high) // 2
        if fits(middle):
            low = middle
        else:
            high = middle
    return low


def _replace(config: Config, section: str, **changes: object) -> Config:
    return dataclasses.replace(config, **{section: dataclasses.replace(getattr(config, section), **changes)})
