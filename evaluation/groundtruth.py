"""Ground truth for place recognition: for each query, the set of reference indices that show its place.

A :class:`GroundTruth` holds one set per query, stored compactly (CSR: one
sorted index array plus row offsets) so that a route of tens of thousands of
frames with generous radii stays small. A query whose set is empty has no true
reference (it was driven where the reference traverse never went, or it fell
outside the positions' coverage); metrics treat it explicitly, see
``docs/metrics.md``.

Three sources:

- positions in metres: reference r is true for query q when the Euclidean
  distance between them is at most the radius (``<=``);
- frame indices (index-aligned sets such as Nordland): reference r is true for
  query q when ``|r - place(q)| <= tolerance`` frames, ``place(q)`` being the
  reference index that shows q's place (q itself for index-aligned sets);
- explicit lists, e.g. a VPR-Bench ``ground_truth_new.npy`` file.

Several radii or tolerances at once share one distance computation.
"""

from __future__ import annotations

import pickle
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Literal, Sequence

import numpy as np

from lostx.core.errors import InputError

Unit = Literal["frames", "m"]

# Queries are processed in blocks so that the (block x references) distance matrix stays near 32 MB.
_BLOCK_ELEMENTS = 4_000_000


@dataclass(frozen=True)
class GroundTruth:
    """Per query, the sorted set of true reference indices."""

    indptr: np.ndarray
    """(n_queries + 1,) int64 offsets: query q's set is ``indices[indptr[q]:indptr[q + 1]]``."""
    indices: np.ndarray
    """int64 reference indices, sorted and unique within each query's slice."""
    n_references: int
    tolerance: float
    """The localization radius (metres) or frame tolerance this set was built with."""
    unit: Unit
    source: str = ""
    """Where it came from, for messages and reports (a file, 'positions', 'index-aligned')."""

    def __post_init__(self) -> None:
        if self.indptr.ndim != 1 or len(self.indptr) < 1 or self.indptr[0] != 0:
            raise ValueError("indptr must be a 1-D array starting at 0")
        if self.indptr[-1] != len(self.indices):
            raise ValueError("indptr[-1] must equal the number of indices")

    @property
    def n_queries(self) -> int:
        return len(self.indptr) - 1

    def matches(self, query: int) -> np.ndarray:
        """The true reference indices of ``query`` (sorted; empty when it has none)."""
        return self.indices[self.indptr[query] : self.indptr[query + 1]]

    @property
    def counts(self) -> np.ndarray:
        """(n_queries,) number of true references per query."""
        return np.diff(self.indptr)

    @property
    def has_match(self) -> np.ndarray:
        """(n_queries,) bool: the query has at least one true reference."""
        return self.counts > 0

    def contains(self, queries: np.ndarray, references: np.ndarray) -> np.ndarray:
        """Element-wise: is ``references[i]`` in the true set of ``queries[i]``? Negative references are never true."""
        queries = np.asarray(queries, dtype=np.int64)
        references = np.asarray(references, dtype=np.int64)
        queries, references = np.broadcast_arrays(queries, references)
        valid = (references >= 0) & (references < self.n_references)
        if len(self.indices) == 0:
            return np.zeros(queries.shape, dtype=bool)
        # Rows are in query order and sorted within, so (query, reference) keys are globally sorted.
        keys = self._keys()
        wanted = queries * self.n_references + np.where(valid, references, 0)
        pos = np.searchsorted(keys, wanted)
        found = keys[np.minimum(pos, len(keys) - 1)] == wanted
        return found & valid

    def is_correct(self, predictions: np.ndarray) -> np.ndarray:
        """(n_queries,) bool: query q's predicted reference ``predictions[q]`` is one of its true references."""
        predictions = np.asarray(predictions)
        if predictions.shape != (self.n_queries,):
            raise InputError(f"{len(predictions)} predictions for {self.n_queries} queries in the ground truth")
        return self.contains(np.arange(self.n_queries), predictions)

    def to_dense(self) -> np.ndarray:
        """(n_queries, n_references) bool matrix; for small sets and tests."""
        dense = np.zeros((self.n_queries, self.n_references), dtype=bool)
        rows = np.repeat(np.arange(self.n_queries), self.counts)
        dense[rows, self.indices] = True
        return dense

    def widened(self, frames: int) -> "GroundTruth":
        """Each true reference r also makes r - frames ... r + frames true (clipped to the map).

        Gives frame tolerances on top of an explicit list (VPR-Bench); tolerance adds up.
        """
        if frames < 0:
            raise InputError(f"frame tolerance must be >= 0, got {frames}")
        if frames == 0:
            return self
        sets = []
        offsets = np.arange(-frames, frames + 1)
        for q in range(self.n_queries):
            base = self.matches(q)
            grown = (base[:, None] + offsets[None, :]).ravel()
            sets.append(grown[(grown >= 0) & (grown < self.n_references)])
        return from_lists(sets, self.n_references, self.tolerance + frames, "frames", self.source)

    def _keys(self) -> np.ndarray:
        rows = np.repeat(np.arange(self.n_queries, dtype=np.int64), self.counts)
        return rows * self.n_references + self.indices


def from_lists(
    sets: Sequence[Iterable[int]], n_references: int, tolerance: float = 0.0, unit: Unit = "frames", source: str = ""
) -> GroundTruth:
    """Ground truth from one iterable of reference indices per query (duplicates are merged)."""
    arrays = []
    for q, refs in enumerate(sets):
        arr = np.unique(np.asarray(list(refs), dtype=np.int64))
        if len(arr) and (arr[0] < 0 or arr[-1] >= n_references):
            bad = arr[0] if arr[0] < 0 else arr[-1]
            where = f"{source}: " if source else ""
            raise InputError(f"{where}query {q}: reference index {bad} is outside 0..{n_references - 1}")
        arrays.append(arr)
    indptr = np.zeros(len(arrays) + 1, dtype=np.int64)
    indptr[1:] = np.cumsum([len(a) for a in arrays])
    indices = np.concatenate(arrays) if arrays else np.zeros(0, dtype=np.int64)
    return GroundTruth(indptr, indices.astype(np.int64), int(n_references), float(tolerance), unit, source)


def from_indices(
    query_places: np.ndarray,
    n_references: int,
    tolerances: float | Sequence[float],
    reference_places: np.ndarray | None = None,
    source: str = "index-aligned",
) -> list[GroundTruth]:
    """Frame-tolerance ground truth: r is true for q when ``|reference_places[r] - query_places[q]| <= tolerance``.

    Places are frame numbers along one shared route. ``reference_places``
    defaults to ``arange(n_references)`` (every reference frame is its own
    place) and must be increasing; a subsampled traverse passes the original
    frame numbers it kept. ``query_places[q]`` is the place query q shows, or a
    negative number when it shows no place of the reference traverse. For
    index-aligned sets it is ``arange(n_queries)`` (see :func:`index_aligned`).
    One result per tolerance.
    """
    places = np.asarray(query_places, dtype=np.int64)
    if reference_places is None:
        ref = np.arange(n_references, dtype=np.int64)
    else:
        ref = np.asarray(reference_places, dtype=np.int64)
        if len(ref) != n_references:
            raise InputError(f"{len(ref)} reference places for {n_references} references")
        if len(ref) > 1 and np.any(np.diff(ref) <= 0):
            raise InputError("reference places must be strictly increasing (frames in route order)")
    out = []
    for tol in _as_list(tolerances):
        if tol < 0 or tol != int(tol):
            raise InputError(f"frame tolerance must be a whole number >= 0, got {tol}")
        k = int(tol)
        # Each query's true set is the contiguous run of references with places in [p - k, p + k].
        lo = np.searchsorted(ref, places - k, side="left")
        hi = np.searchsorted(ref, places + k, side="right")
        hi = np.where(places < 0, lo, hi)
        counts = hi - lo
        indptr = np.zeros(len(places) + 1, dtype=np.int64)
        indptr[1:] = np.cumsum(counts)
        starts = np.repeat(lo - indptr[:-1], counts)
        indices = np.arange(indptr[-1], dtype=np.int64) + starts
        out.append(GroundTruth(indptr, indices, int(n_references), float(k), "frames", source))
    return out


def index_aligned(n_queries: int, n_references: int, tolerances: float | Sequence[float]) -> list[GroundTruth]:
    """Same index = same place: r is true for q when ``|r - q| <= tolerance``.

    A query past the end of the reference traverse matches only references within the tolerance of its index.
    """
    places = np.arange(n_queries, dtype=np.int64)
    return from_indices(places, n_references, tolerances, source="index-aligned")


def from_positions(
    query_positions: np.ndarray,
    reference_positions: np.ndarray,
    radii: float | Sequence[float],
    source: str = "positions",
) -> list[GroundTruth]:
    """Metric ground truth: r is true for q when ``||p_q - p_r|| <= radius`` (metres). One result per radius.

    Positions are (N, 2) in one shared metric frame. A non-finite position
    (unknown) matches nothing: such a query has no true reference.
    """
    q = _positions(query_positions, "query")
    r = _positions(reference_positions, "reference")
    rad = _as_list(radii)
    for value in rad:
        if not np.isfinite(value) or value < 0:
            raise InputError(f"localization radius must be a finite number of metres >= 0, got {value}")
    radii_sq = np.asarray(rad, dtype=np.float64) ** 2
    per_radius: list[list[np.ndarray]] = [[] for _ in rad]
    block = max(1, _BLOCK_ELEMENTS // max(1, len(r)))
    for start in range(0, len(q), block):
        diff = q[start : start + block, None, :] - r[None, :, :]
        d2 = np.einsum("qrk,qrk->qr", diff, diff)
        d2[~np.isfinite(d2)] = np.inf
        for k, limit in enumerate(radii_sq):
            within = d2 <= limit
            per_radius[k].extend(np.flatnonzero(row) for row in within)
    out = []
    for k, value in enumerate(rad):
        sets = per_radius[k]
        indptr = np.zeros(len(sets) + 1, dtype=np.int64)
        indptr[1:] = np.cumsum([len(s) for s in sets])
        indices = np.concatenate(sets).astype(np.int64) if sets else np.zeros(0, dtype=np.int64)
        out.append(GroundTruth(indptr, indices, len(r), float(value), "m", source))
    return out


def load_vprbench(path: str | Path, n_queries: int, n_references: int) -> GroundTruth:
    """A VPR-Bench ``ground_truth_new.npy``: one row per query, ``[query_index, reference_indices]``.

    The file is a NumPy object array of shape (n_queries, 2) saved with pickle
    (VPR-Bench's own format), so only load files you trust. Row k must be for
    query k (VPR-Bench reads the rows by position); the reference indices may be
    a list, range, array or a single integer, and index the reference images in
    VPR-Bench's order (sorted by the integer value of the file stem).
    """
    path = Path(path)
    try:
        data = np.load(path, allow_pickle=True)
    except FileNotFoundError:
        raise InputError(f"ground-truth file not found: {path}") from None
    except (ValueError, OSError, EOFError, pickle.UnpicklingError) as exc:
        raise InputError(f"{path}: not a readable .npy file ({exc})") from None
    if data.ndim != 2 or data.shape[1] != 2:
        raise InputError(f"{path}: expected rows of [query_index, reference_indices] (shape (N, 2)), got {data.shape}")
    if len(data) != n_queries:
        raise InputError(f"{path}: {len(data)} rows for {n_queries} query images; expected one row per query")
    sets = []
    for row, (query, refs) in enumerate(data):
        try:
            q = int(query)
        except (TypeError, ValueError):
            raise InputError(f"{path}: row {row}: query index {query!r} is not an integer") from None
        if q != row:
            raise InputError(f"{path}: row {row} is for query {q}; rows must be in query order 0..{n_queries - 1}")
        try:
            values = np.atleast_1d(np.asarray(list(refs) if not np.isscalar(refs) else [refs]))
            ints = values.astype(np.int64)
        except (TypeError, ValueError):
            raise InputError(f"{path}: row {row}: reference indices {refs!r} are not integers") from None
        if len(values) and not np.array_equal(ints, values.astype(np.float64)):
            raise InputError(f"{path}: row {row}: reference indices {refs!r} are not integers")
        bad = ints[(ints < 0) | (ints >= n_references)]
        if len(bad):
            raise InputError(
                f"{path}: row {row}: reference index {int(bad[0])} is outside 0..{n_references - 1} "
                f"({n_references} reference images)"
            )
        sets.append(ints)
    return from_lists(sets, n_references, 0.0, "frames", str(path))


def _as_list(values: float | Sequence[float]) -> list[float]:
    if np.isscalar(values):
        return [float(values)]  # type: ignore[arg-type]
    out = [float(v) for v in values]  # type: ignore[union-attr]
    if not out:
        raise InputError("no tolerance given")
    return out


def _positions(positions: np.ndarray | None, which: str) -> np.ndarray:
    if positions is None:
        raise InputError(f"the {which} traverse has no positions; metric ground truth needs positions for both")
    arr = np.asarray(positions, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{which} positions must be (N, 2) metres, got shape {arr.shape}")
    return arr
