"""Comparing layout grids: the mean over channels of the Pearson correlation over the cells both grids
observed, best over small sideways shifts; as they are (the query viewing the stretch the way the map
frame did) or with the query turned 180 degrees (viewing it from the other end).

Every term of a masked correlation is a sum over the common cells (their count, the sums of each grid's
values and squares, the sum of products), so one comparison of a query with N map grids is a few matrix
products (:class:`GridStack` holds the map side ready for them):

    r_c = (S_xy - S_x S_y / n) / sqrt((S_xx - S_x^2 / n) (S_yy - S_y^2 / n)),   s = sum_c w_c r_c / sum_c w_c

A channel constant over the common cells has no correlation (0); fewer than ``min_cells`` common cells give
no similarity at all (-inf).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .grid import LayoutGrid


class GridStack:
    """N grids (all of one shape) prepared as the map side of comparisons."""

    def __init__(self, values: np.ndarray, masks: np.ndarray) -> None:
        """``values`` (N, C, A, X), ``masks`` (N, A, X)."""
        n, c, a, x = values.shape
        self.n, self.channels, self.shape = n, c, (a, x)
        m = masks.reshape(n, 1, a * x).astype(np.float32)
        v = values.reshape(n, c, a * x).astype(np.float32) * m
        self.mask_t = np.ascontiguousarray(m[:, 0].T)  # (P, N)
        # (P, N * 2C): each grid's masked values and squares, for the query's mask to sum over.
        self.sums_t = np.ascontiguousarray(np.concatenate([v, v * v], axis=1).transpose(2, 0, 1).reshape(a * x, -1))
        self.values = np.ascontiguousarray(v.transpose(1, 2, 0))  # (C, P, N)

    @classmethod
    def of(cls, grids: Sequence[LayoutGrid]) -> "GridStack":
        return cls(np.stack([g.values for g in grids]), np.stack([g.mask for g in grids]))

    def rows(self, indices: np.ndarray) -> "GridStack":
        """The grids ``indices`` as a stack of their own (their prepared sums taken as they are)."""
        out = GridStack.__new__(GridStack)
        out.n, out.channels, out.shape = len(indices), self.channels, self.shape
        out.mask_t = np.ascontiguousarray(self.mask_t[:, indices])
        sums = self.sums_t.reshape(self.sums_t.shape[0], self.n, -1)[:, indices]
        out.sums_t = np.ascontiguousarray(sums.reshape(self.sums_t.shape[0], -1))
        out.values = np.ascontiguousarray(self.values[:, :, indices])
        return out


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
    c = maps.channels
    variants = [shifted(query, s) for s in range(-shifts, shifts + 1)]
    m = np.stack([v.mask.ravel() for v in variants]).astype(np.float32)  # (S, P)
    q = np.stack([v.values.reshape(c, -1) for v in variants]).astype(np.float32) * m[:, None, :]  # (S, C, P)
    s = len(variants)
    # Query-side sums over each map grid's mask: n, S_x, S_xx.
    own = np.concatenate([m[:, None, :], q, q * q], axis=1).reshape(-1, m.shape[1]) @ maps.mask_t
    own = own.reshape(s, 1 + 2 * c, maps.n)
    n, sx, sxx = own[:, :1], own[:, 1 : 1 + c], own[:, 1 + c :]
    # Map-side sums over the query's mask: S_y, S_yy.
    theirs = (m @ maps.sums_t).reshape(s, maps.n, 2 * c).transpose(0, 2, 1)
    sy, syy = theirs[:, :c], theirs[:, c:]
    sxy = np.matmul(q.transpose(1, 0, 2), maps.values).transpose(1, 0, 2)  # (S, C, N)
    with np.errstate(divide="ignore", invalid="ignore"):
        count = np.maximum(n, 1.0)
        cov = sxy - sx * sy / count
        var = (sxx - sx * sx / count) * (syy - sy * sy / count)
        r = np.where(var > 1e-12, cov / np.sqrt(np.maximum(var, 1e-12)), 0.0)
    w = np.asarray(weights, dtype=np.float64)
    score = np.tensordot(w / w.sum(), r, axes=(0, 1))  # (S, N)
    score = np.where(n[:, 0] >= min_cells, score, -np.inf)
    return score.max(axis=0)
