"""Comparing layout grids: the mean over channels of the Pearson correlation over the cells both grids
observed, best over small sideways shifts; as they are (the query viewing the stretch the way the map
frame did) or with the query turned 180 degrees (viewing it from the other end).

Every term of a masked correlation is a sum over the common cells (their count, the sums of each grid's
values and squares, the sum of products), so one comparison of a query with N map grids is a few matrix
products (:class:`GridStack` holds the map side ready for them):

    r_c = (S_xy - S_x S_y / n) / sqrt((S_xx - S_x^2 / n) (S_yy - S_y^2 / n)),   s = sum_c w_c r_c / sum_c w_c

A channel constant over the common cells has no correlation (0); fewer than ``min_cells`` common cells give
no similarity at all (-inf).

The map grid's own sums n, S_y and S_yy run over the cells the query observed, nearly all of them: they are
the grid's totals less its cells the query did not observe (or, for a query that observed few, the sums over
those it did), so that a comparison reads only a few of the map's cells for them, and no squares at all.

Against a map's grids (one-byte levels) the query's values are made whole numbers too (:func:`query_levels`):
every sum is then exact, so a comparison gives the same bits whatever BLAS, thread count or CPU computes it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .grid import LayoutGrid, stored_half, unpack_levels


class GridStack:
    """N grids (all of one shape) prepared as the map side of comparisons: the mask and the values (zero where
    unobserved) of every grid and cell, with each grid's totals over its cells.

    The values are kept in units of ``1 / scale`` per channel: a map's are its stored one-byte levels (a quarter of
    the bytes to read per comparison, each block of grids widened to float32 as it is used), whose sums (and the
    totals less a few cells) are exact integers."""

    def __init__(self, values: np.ndarray, masks: np.ndarray, scale: np.ndarray | None = None) -> None:
        """``values`` (N, C, A, X) in units of ``1 / scale`` ((C,), default 1; one-byte levels are kept as they
        are, anything else as float32), ``masks`` (N, A, X)."""
        n, c, a, x = values.shape
        dtype = np.uint8 if values.dtype == np.uint8 else np.float32
        mask = masks.reshape(n, 1, a * x).astype(dtype)
        grids = np.concatenate([mask, values.reshape(n, c, a * x).astype(dtype) * mask], axis=1)
        self._of_grids(grids, np.ones(c) if scale is None else np.asarray(scale, dtype=np.float64).reshape(c))

    def _of_grids(self, grids: np.ndarray, scale: np.ndarray) -> None:
        cells = np.ascontiguousarray(grids.transpose(1, 2, 0))
        self._set(grids, cells, scale, cells.sum(axis=1, dtype=np.float64),
                  np.einsum("cpn,cpn->cn", cells[1:], cells[1:], dtype=np.float64))

    def __reduce__(self) -> tuple:
        """Pickled as its grids and scale alone (to another process), the rest made again from them."""
        return _stack_of_grids, (self.grids, self.scale)

    def _set(self, grids: np.ndarray, cells: np.ndarray, scale: np.ndarray, totals: np.ndarray,
             square_totals: np.ndarray) -> None:
        self.n, self.channels = grids.shape[0], grids.shape[1] - 1
        self.grids = grids
        """(N, 1 + C, P) each grid's mask and values: a subset of the grids is a gather of whole rows."""
        self.cells = cells
        """(1 + C, P, N) the same, cell-major: a set of cells is a gather of whole rows."""
        self.blocks = [(block, np.ascontiguousarray(cells[:, :, block])) for block in blocks(self.n)]
        """The cells of each block of grids (:func:`blocks`), each whole in memory: widened at once."""
        self.scale = scale
        self.totals = totals
        """(1 + C, N) float64: each grid's observed cells and sum of values over them."""
        self.square_totals = square_totals
        """(C, N) float64: each grid's sum of squared values."""

    @property
    def levels(self) -> bool:
        """Whether the values are one-byte levels (a map's): the query's are then made whole numbers too
        (:func:`query_levels`), and every sum of a comparison is exact."""
        return self.grids.dtype == np.uint8

    @classmethod
    def of(cls, grids: Sequence[LayoutGrid]) -> "GridStack":
        return cls(np.stack([g.values for g in grids]), np.stack([g.mask for g in grids]))

    def rows(self, indices: np.ndarray) -> "GridStack":
        """The grids ``indices`` as a stack of their own (their prepared arrays taken as they are)."""
        out = GridStack.__new__(GridStack)
        grids = self.grids[indices]
        out._set(grids, np.ascontiguousarray(grids.transpose(1, 2, 0)), self.scale, self.totals[:, indices],
                 self.square_totals[:, indices])
        return out


class StoredGrids:
    """A map's grids left where they are stored (memory-mapped rows of :func:`~.grid.pack_both`'s values and mask
    bits), read a few at a time: a large map compares only the frames its sequence filter looks at, and the whole
    stack (some 6 kB a frame per heading) would not fit in memory at a city's size."""

    def __init__(self, values: np.ndarray, bits: np.ndarray, shape: tuple[int, int], other_end: bool) -> None:
        self.values, self.bits, self.shape, self.other_end = values, bits, shape, other_end
        self.n = len(values)

    def rows(self, indices: np.ndarray) -> GridStack:
        """The grids ``indices`` as a stack of their own, as :meth:`GridStack.rows` of :meth:`whole` gives them (the
        same levels, masks and totals)."""
        indices = np.asarray(indices, dtype=np.int64)
        return self._stack(np.asarray(self.values[indices]), np.asarray(self.bits[indices]))

    def whole(self) -> GridStack:
        """Every grid, read into memory as one stack."""
        return self._stack(self.values, self.bits)

    def _stack(self, values: np.ndarray, bits: np.ndarray) -> GridStack:
        # The stored levels as they are: their sums over cells are exact.
        return GridStack(*unpack_levels(*stored_half(values, bits, self.shape, self.other_end), self.shape))


def _stack_of_grids(grids: np.ndarray, scale: np.ndarray) -> GridStack:
    stack = GridStack.__new__(GridStack)
    stack._of_grids(grids, scale)
    return stack


def shifted(grid: LayoutGrid, shift: int) -> LayoutGrid:
    """The grid moved ``shift`` cells across (positive: to the right), the cells moved in unobserved."""
    if shift == 0:
        return grid
    values = np.zeros_like(grid.values)
    mask = np.zeros_like(grid.mask)
    if shift > 0:
        values[:, :, shift:], mask[:, shift:] = grid.values[:, :, :-shift], grid.mask[:, :-shift]
    else:
        values[:, :, :shift], mask[:, :shift] = grid.values[:, :, -shift:], grid.mask[:, -shift:]
    return LayoutGrid(values, mask)


def similarity(query: LayoutGrid, maps: GridStack, weights: np.ndarray, shifts: int = 0,
               min_cells: int = 1) -> np.ndarray:
    """(N,) the query's similarity with each map grid, best over sideways shifts of up to ``shifts`` cells
    (the weighted mean over channels of the masked Pearson correlation; -inf without ``min_cells`` in common)."""
    return similarities([query], maps, weights, shifts, min_cells)[0]


def similarities(queries: Sequence[LayoutGrid], maps: GridStack, weights: np.ndarray, shifts: int = 0,
                 min_cells: int = 1) -> np.ndarray:
    """(Q, N) :func:`similarity` of several queries (a frame's grid under both headings) in one pass over the
    map's grids."""
    offsets = range(-shifts, shifts + 1)
    variants = [shifted(g, s) for g in queries for s in offsets]
    score = correlations(variants, maps, weights, min_cells)
    return score.reshape(len(queries), len(offsets), maps.n).max(axis=1)


def correlations(variants: Sequence[LayoutGrid], maps: GridStack, weights: np.ndarray, min_cells: int) -> np.ndarray:
    """(V, N) the weighted mean masked correlation of each query variant with each map grid."""
    c = maps.channels
    m = np.stack([g.mask.ravel() for g in variants]).astype(np.float32)  # (V, P)
    q = np.stack([g.values.reshape(c, -1) for g in variants]).astype(np.float32) * m[:, None, :]  # (V, C, P)
    if maps.levels:
        q = query_levels(q, m)
    n, sy, syy = observed_sums(maps, m)
    sx, sxx, sxy = query_sums(maps, q)
    with np.errstate(divide="ignore", invalid="ignore"):
        count = np.maximum(n, 1.0)
        cov = sxy - sx * sy / count
        var = (sxx - sx * sx / count) * (syy - sy * sy / count)
        r = np.where(var > 1e-12, cov / np.sqrt(np.maximum(var, 1e-12)), 0.0)
    w = np.asarray(weights, dtype=np.float64)
    score = (r * (w / w.sum())[:, None]).sum(axis=1)  # (V, N), each sum channel by channel in order (no BLAS)
    return np.where(n[:, 0] >= min_cells, score, -np.inf)


@dataclass(frozen=True)
class Alignment:
    """A grid turned and shifted sideways as it best fits another."""

    grid: LayoutGrid
    """The grid so turned and shifted."""
    turn: float
    """Degrees, anticlockwise seen from above."""
    shift: int
    """Cells, positive to the right."""
    similarity: float


TURNS: tuple[float, ...] = (-5.0, 0.0, 5.0)
"""Degrees the query's grid is turned about its centre when the most similar map grids are compared again: views of
a curve from its two ends are not exactly 180 degrees apart, and the gathered frames' motion and the camera's
mounting are known to a few degrees. Not a setting: no turns won scene-0916 by 4 of 106 queries and lost scene-0523
6 of 132, 5 degrees the reverse, 8 lost both (benchmarks/results/study_layout.md)."""


def aligned(view: LayoutGrid, target: LayoutGrid, weights: np.ndarray, shifts: int, turns: Sequence[float],
            min_cells: int) -> Alignment:
    """``view`` turned by each of ``turns`` (0 included) and shifted by up to ``shifts`` cells, as it best fits
    ``target`` (the least turned and shifted of equals)."""
    moves = [(angle, shift) for angle in sorted({0.0, *turns}, key=abs)
             for shift in sorted(range(-shifts, shifts + 1), key=abs)]
    candidates = [shifted(view.rotated(angle), shift) for angle, shift in moves]
    scores = correlations(candidates, GridStack.of([target]), weights, min_cells)[:, 0]
    best = int(np.argmax(scores))  # the first of equals
    return Alignment(candidates[best], moves[best][0], moves[best][1], float(scores[best]))


def refined(views: Sequence[LayoutGrid], maps: GridStack, rows: np.ndarray, weights: np.ndarray, shifts: int,
            turns: Sequence[float], min_cells: int, whole: bool = False) -> np.ndarray:
    """(H, K) each view's best similarity with its own ``rows`` ((H, K) map grids) over the sideways shifts of up to
    ``shifts`` cells and the ``turns`` (degrees, each also shifted), the view as it lies unshifted left out unless
    ``whole``.

    Every view, variant and map grid in a few batched products: each heading's grids are few, so that the cost lies
    in the number of calls more than in the arithmetic. The map's sums of squared levels (beyond float32's exact
    integers) are summed in float64."""
    variants = _variants(views, shifts, turns, whole)  # (H, V, 1 + C, P)
    m, q = variants[:, :, 0], variants[:, :, 1:]
    if maps.levels:
        q = query_levels(q, m)
    h, v, c, p = q.shape
    k = rows.shape[1]
    cells = np.ascontiguousarray(maps.grids[rows].transpose(0, 2, 1, 3), dtype=np.float32)  # (H, 1 + C, K, P)
    mask, y = cells[:, 0], cells[:, 1:]
    own = mask @ np.concatenate([m[:, :, None], q, q * q], axis=2).reshape(h, v * (1 + 2 * c), p).transpose(0, 2, 1)
    own = own.reshape(h, k, v, 1 + 2 * c).astype(np.float64)
    n, sx, sxx = own[..., 0], own[..., 1: 1 + c], own[..., 1 + c:]  # (H, K, V), (H, K, V, C) twice
    seen = m.transpose(0, 2, 1)  # (H, P, V)
    unit = 1.0 / maps.scale

    def by_grid(sums: np.ndarray) -> np.ndarray:
        """(H, C * K, V) or (H, C, K, V) sums as (H, K, V, C) float64."""
        return sums.reshape(h, c, k, v).transpose(0, 2, 3, 1).astype(np.float64)

    sy = by_grid(y.reshape(h, c * k, p) @ seen) * unit
    squares = np.square(y, dtype=np.float64).reshape(h, c * k, p)
    syy = by_grid(squares @ seen.astype(np.float64)) * unit**2
    sxy = by_grid(y @ q.transpose(0, 2, 3, 1)) * unit
    with np.errstate(divide="ignore", invalid="ignore"):
        count = np.maximum(n, 1.0)[..., None]
        cov = sxy - sx * sy / count
        var = (sxx - sx * sx / count) * (syy - sy * sy / count)
        r = np.where(var > 1e-12, cov / np.sqrt(np.maximum(var, 1e-12)), 0.0)
    w = np.asarray(weights, dtype=np.float64)
    score = (r * (w / w.sum())).sum(axis=3)  # (H, K, V)
    return np.where(n >= min_cells, score, -np.inf).max(axis=2)


def _variants(views: Sequence[LayoutGrid], shifts: int, turns: Sequence[float], whole: bool = False) -> np.ndarray:
    """(H, V, 1 + C, P) float32 each view's mask and values (zero where unobserved) shifted sideways by every offset
    up to ``shifts`` cells (0 only where ``whole``), then turned by each of ``turns`` and shifted by every offset (0
    included)."""
    turned = [[view] + [view.rotated(angle) for angle in turns] for view in views]
    cells = np.stack([[np.concatenate([g.mask[None], g.values]) for g in row] for row in turned]).astype(np.float32)
    a, x = cells.shape[-2:]
    padded = np.zeros(cells.shape[:-1] + (x + 2 * shifts,), dtype=np.float32)
    padded[..., shifts: shifts + x] = cells
    # Window j of the padded columns is the grid moved ``shifts - j`` cells to the right, moved-in cells unobserved.
    windows = np.lib.stride_tricks.sliding_window_view(padded, x, axis=-1)  # (H, 1 + T, 1 + C, A, 2S + 1, X)
    which = [(0, j) for j in range(2 * shifts + 1) if whole or j != shifts]
    which += [(t, j) for t in range(1, len(turns) + 1) for j in range(2 * shifts + 1)]
    turn, window = np.array(which).T
    picked = windows[:, turn, :, :, window]  # (V, H, 1 + C, A, X)
    return np.ascontiguousarray(picked.transpose(1, 0, 2, 3, 4)).reshape(len(views), len(which), cells.shape[2], a * x)


def observed_sums(maps: GridStack, m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n (V, 1, N), S_y and S_yy (V, C, N), float64: each map grid's count, sum and sum of squares over the cells
    each variant (mask ``m`` (V, P)) observed. Summed over the fewer of the cells some variant observed and those
    some variant did not (the grid's totals less them), so that a query observing nearly every cell reads only a
    few of the map's. A map's levels are integers: their sums (up to 258 cells of 255^2) are exact either way."""
    seen, missed = m.any(axis=0), ~m.all(axis=0)
    if seen.sum() <= missed.sum():
        cells, weight, base, squares = np.flatnonzero(seen), m, 0.0, 0.0
    else:
        cells, weight = np.flatnonzero(missed), m - 1.0
        base, squares = maps.totals, maps.square_totals
    weight = np.ascontiguousarray(weight[:, cells]).T  # (R, V)
    taken = maps.cells[:, cells, :].astype(np.float32)  # (1 + C, R, N)
    # As in query_sums, the map grids are the rows of the left operand, both operands transposed.
    sums = base + _grid_last(np.matmul(taken.transpose(0, 2, 1), weight))  # (V, 1 + C, N)
    sq = squares + _grid_last(np.matmul((taken[1:] * taken[1:]).transpose(0, 2, 1), weight))
    unit = 1.0 / maps.scale[:, None]
    return sums[:, :1], sums[:, 1:] * unit, sq * (unit * unit)


def query_sums(maps: GridStack, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """S_x, S_xx and S_xy (V, C, N), float64: the query variants' (values ``q`` (V, C, P), zero where unobserved)
    sums and sums of squares over each map grid's observed cells, and their products with its values.

    Each product has the map grid as a row of the left operand and both operands transposed (what BLAS is given),
    over blocks of two grids or more, so that every map grid's sums are computed alike wherever it lies in the stack:
    exactly against a map's levels (:func:`query_levels`), to float32's rounding against other values."""
    v, c, p = q.shape
    own_right = np.concatenate([q, q * q], axis=1).reshape(2 * v * c, p).T  # (P, 2VC)
    cross_right = np.ascontiguousarray(q.transpose(1, 0, 2)).transpose(0, 2, 1)  # (C, P, V)
    own = np.empty((maps.n, 2 * v * c), dtype=np.float32)
    cross = np.empty((maps.n, c, v), dtype=np.float32)
    # The largest block's cells (the last block may hold one grid more than the others), in cache.
    widened = np.empty(max((stored.size for _, stored in maps.blocks), default=0), dtype=np.float32)
    for block, stored in maps.blocks:
        cells = widened[: stored.size].reshape(stored.shape)  # (1 + C, P, n)
        np.copyto(cells, stored)
        np.matmul(cells[0].T, own_right, out=own[block])
        np.matmul(cells[1:].transpose(0, 2, 1), cross_right, out=cross[block].transpose(1, 0, 2))
    own = np.ascontiguousarray(own.T, dtype=np.float64).reshape(v, 2, c, maps.n)
    return own[:, 0], own[:, 1], _grid_last(cross.transpose(1, 0, 2)) / maps.scale[:, None]


def _grid_last(sums: np.ndarray) -> np.ndarray:
    """(C, N, V) float32 sums as (V, C, N) float64, contiguous for the arithmetic that follows."""
    return np.ascontiguousarray(sums.transpose(2, 0, 1), dtype=np.float64)


EXACT = 2**24
"""float32 holds every whole number below this: sums of whole numbers below it come out exact in any order."""


def query_levels(q: np.ndarray, m: np.ndarray) -> np.ndarray:
    """(..., V, C, P) a query's values (its variants', zero where mask ``m`` (..., V, P) is) as whole numbers: each
    channel's observed values mapped onto 0 to L by one increasing affine map, which no correlation sees, with L as
    large as keeps every sum of a comparison with one-byte map levels exact in float32 (P L^2 and 255 P L below
    :data:`EXACT`: 219 levels on a 20 x 15 grid). The sums then do not depend on the order BLAS adds in, which its
    kernels choose by a map grid's place in a product, by the thread count and by the CPU: every map grid gets the
    same bits wherever it lies, by a thread or in another process, on any machine."""
    cells = q.shape[-1]
    top = min(255, (EXACT - 1) // (255 * cells), int(np.sqrt((EXACT - 1) / cells)))
    seen = m[..., None, :] > 0
    low = np.where(seen, q, np.inf).min(axis=(-3, -1), keepdims=True)
    span = np.where(seen, q, -np.inf).max(axis=(-3, -1), keepdims=True) - low
    usable = np.isfinite(span) & (span > 0)
    unit = np.where(usable, top / np.where(usable, span, 1.0), 0.0)
    return (np.rint((q - np.where(usable, low, 0.0)) * unit) * m[..., None, :]).astype(np.float32)


BLOCK = 128
"""Map grids compared at a time: their cells widened to float32 (8 kB a grid) stay in the cache."""


def blocks(n: int) -> list[slice]:
    """``n`` grids in blocks of ``BLOCK``, the last one of two grids or more (one grid alone would take another
    path through BLAS, summing its products in another order)."""
    starts = list(range(0, n, BLOCK))
    if len(starts) > 1 and n - starts[-1] < 2:
        starts.pop()
    return [slice(a, b) for a, b in zip(starts, starts[1:] + [n])]
