"""How far a recall measured on few queries can be trusted, and whether two methods differ on the same queries.

A recall is k right of n queries: on 34 queries, 27 (79 %) is compatible with anything from about 63 % to 90 %.
The **Wilson score interval** bounds the proportion that would give k of n with the chosen coverage (it stays
inside [0, 1] and behaves at k = 0 and k = n, where the textbook p +- z sqrt(p (1 - p) / n) collapses):

    centre = (k + z^2 / 2) / (n + z^2),   half = z sqrt(k (n - k) / n + z^2 / 4) / (n + z^2)

Two methods answering the same queries are compared pairwise, not by their two recalls: only the queries one
gets right and the other wrong (b and c) say anything about which is better. Under "no difference" each of those
b + c queries is a fair coin, so the **exact McNemar (sign) test** gives the two-sided p-value

    p = min(1, 2 sum_{i <= min(b, c)} C(b + c, i) / 2^(b + c))

A difference of two queries out of 34 has p = 0.5: noise. Several runs of one scene (other frame rates, other
motion sources) are not independent queries, so a p-value over their pooled answers is optimistic. Nor are a
sequence filter's answers to neighbouring frames, which share its window: seven consecutive frames that turn right
together are one event. Counted in **stretches** (each maximal run of consecutive queries that one gets right and
the other wrong counts once), b and c are what such answers can show.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from lostx.core.errors import InputError


def recall_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """The Wilson score interval of a proportion of ``k`` in ``n`` at coverage ``level`` ((nan, nan) for n = 0)."""
    if not 0.0 < level < 1.0:
        raise InputError(f"the interval's level must lie between 0 and 1, got {level}")
    if n < 0 or not 0 <= k <= n:
        raise InputError(f"a proportion needs 0 <= k <= n, got {k} of {n}")
    if n == 0:
        return float("nan"), float("nan")
    z = NormalDist().inv_cdf(0.5 + level / 2.0)
    centre = (k + z * z / 2.0) / (n + z * z)
    half = z * math.sqrt(k * (n - k) / n + z * z / 4.0) / (n + z * z)
    return max(0.0, centre - half), min(1.0, centre + half)


def sign_test(b: int, c: int) -> float:
    """The exact two-sided p-value of ``b`` against ``c`` discordant pairs (McNemar's test; 1 when both are 0)."""
    if b < 0 or c < 0:
        raise InputError(f"discordant counts must not be negative, got {b} and {c}")
    n = b + c
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(b, c) + 1))
    return min(1.0, 2.0 * tail / 2.0**n)


@dataclass(frozen=True)
class PairedComparison:
    """Two methods' answers to the same queries, right or wrong."""

    n: int
    """Queries compared."""
    only_first: int
    """Queries the first method gets right and the second wrong (or stretches of them)."""
    only_second: int
    """Queries the second method gets right and the first wrong (or stretches of them)."""
    p_value: float
    """The exact McNemar test's two-sided p-value (:func:`sign_test`)."""

    @property
    def difference(self) -> int:
        """How many more queries the first method gets right."""
        return self.only_first - self.only_second


def paired_comparison(first: np.ndarray, second: np.ndarray, stretches: bool = False) -> PairedComparison:
    """Compare two methods by which queries each gets right (``first``, ``second``: (n,) bool, the same queries in
    the same order); with ``stretches``, each run of consecutive queries only one of them gets right counts once
    (answers that depend on their neighbours', a sequence filter's)."""
    first, second = np.asarray(first, dtype=bool), np.asarray(second, dtype=bool)
    if first.shape != second.shape or first.ndim != 1:
        raise InputError(f"a paired comparison needs two answers per query, got shapes {first.shape} and "
                         f"{second.shape}")
    only_first, only_second = first & ~second, second & ~first
    if stretches:
        b, c = _starts(only_first), _starts(only_second)
    else:
        b, c = int(only_first.sum()), int(only_second.sum())
    return PairedComparison(n=len(first), only_first=b, only_second=c, p_value=sign_test(b, c))


def _starts(flags: np.ndarray) -> int:
    """How many runs of consecutive True ``flags`` holds."""
    return int(np.sum(flags & ~np.concatenate([[False], flags[:-1]])))
