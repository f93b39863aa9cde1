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
    """N grids (all of one shape) prepared as the map side of comparisons: each array grid-major, so that a
    comparison streams through it once with every query variant at a time, and a subset of grids is a gather
    of whole rows."""

    def __init__(self, values: np.ndarray, masks: np.ndarray) -> None:
        """``values`` (N, C, A, X), ``masks`` (N, A, X)."""
        n, c, a, x = values.shape
        self.n, self.channels, self.shape = n, c, (a, x)
        m = masks.reshape(n, 1, a * x).astype(np.float32)
        v = values.reshape(n, c, a * x).astype(np.float32) * m
        self.mask = np.ascontiguousarray(m[:, 0])  # (N, P)
        self.values = np.ascontiguousarray(v.transpose(1, 0, 2))  # (C, N, P), zero where unobserved
        self.squares = self.values * self.values  # (C, N, P)

    @classmethod
    def of(cls, grids: Sequence[LayoutGrid]) -> "GridStack":
        return cls(np.stack([g.values for g in grids]), np.stack([g.mask for g in grids]))

    def rows(self, indices: np.ndarray) -> "GridStack":
        """The grids ``indices`` as a stack of their own (their prepared arrays taken as they are)."""
        out = GridStack.__new__(GridStack)
        out.n, out.channels, out.shape = len(indices), self.channels, self.shape
        out.mask = self.mask[indices]
        out.values = self.values[:, indices]
        out.squares = self.squares[:, indices]
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
    return similarities([query], maps, weights, shifts, min_cells)[0]


def similarities(queries: Sequence[LayoutGrid], maps: GridStack, weights: np.ndarray, shifts: int = 0,
                 min_cells: int = 1) -> np.ndarray:
    """(Q, N) :func:`similarity` of several queries (a frame's grid under both headings, its turns) in one
    pass over the map's grids."""
    c, k = maps.channels, 2 * shifts + 1
    variants = [shifted(g, s) for g in queries for s in range(-shifts, shifts + 1)]
    v = len(variants)
    m = np.stack([g.mask.ravel() for g in variants]).astype(np.float32)  # (V, P)
    q = np.stack([g.values.reshape(c, -1) for g in variants]).astype(np.float32) * m[:, None, :]  # (V, C, P)
    # Query-side sums over each map grid's mask: n, S_x, S_xx.
    own = maps.mask @ np.concatenate([m[:, None, :], q, q * q], axis=1).reshape(v * (1 + 2 * c), -1).T
    own = own.reshape(maps.n, v, 1 + 2 * c).transpose(1, 2, 0)  # (V, 1 + 2C, N)
    n, sx, sxx = own[:, :1], own[:, 1 : 1 + c], own[:, 1 + c :]
    # Map-side sums over the query's mask, and the products, channel by channel: S_xy and S_y, then S_yy.
    right = np.concatenate([q.transpose(1, 2, 0), np.broadcast_to(m.T, (c, *m.T.shape))], axis=2)  # (C, P, 2V)
    cross = np.matmul(maps.values, right)  # (C, N, 2V)
    sxy, sy = cross[:, :, :v].transpose(2, 0, 1), cross[:, :, v:].transpose(2, 0, 1)  # (V, C, N)
    syy = (maps.squares.reshape(-1, m.shape[1]) @ m.T).reshape(c, maps.n, v).transpose(2, 0, 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        count = np.maximum(n, 1.0)
        cov = sxy - sx * sy / count
        var = (sxx - sx * sx / count) * (syy - sy * sy / count)
        r = np.where(var > 1e-12, cov / np.sqrt(np.maximum(var, 1e-12)), 0.0)
    w = np.asarray(weights, dtype=np.float64)
    score = np.tensordot(w / w.sum(), r, axes=(0, 1))  # (V, N)
    score = np.where(n[:, 0] >= min_cells, score, -np.inf)
    return score.reshape(len(queries), k, maps.n).max(axis=1)
