"""The paper's semantic classes as named groups of a model's class ids.

A descriptor class (road, building, vegetation) is a group of the model's own
classes, configured by name: for the ADE20K model, building = building + house.
Grouping sums the member probabilities, so m_is stays a distribution; the
label space is the groups followed by every model class in no group.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from ..errors import InputError


@dataclass(frozen=True)
class ClassGroups:
    names: tuple[str, ...]
    """Descriptor classes, in descriptor order."""
    members: tuple[tuple[str, ...], ...]
    """The model's class names grouped into each descriptor class."""
    label_names: tuple[str, ...]
    """Names of the grouped label space: the groups, then the ungrouped model classes."""
    matrix: np.ndarray
    """(S, C) 0/1: grouped label s sums model classes c where matrix[s, c] == 1."""

    @classmethod
    def from_spec(cls, spec: Mapping[str, Sequence[str]], class_names: Sequence[str]) -> "ClassGroups":
        index = {name: i for i, name in enumerate(class_names)}
        taken: dict[str, str] = {}
        rows: list[np.ndarray] = []
        if not spec:
            raise InputError("no semantic classes configured for the descriptor")
        for group, members in spec.items():
            row = np.zeros(len(class_names), dtype=np.float32)
            if not members:
                raise InputError(f"class group '{group}' has no member classes")
            for member in members:
                if member not in index:
                    raise InputError(
                        f"class group '{group}': the model has no class '{member}'; "
                        f"its classes are: {', '.join(class_names)}"
                    )
                if member in taken:
                    raise InputError(f"class '{member}' is in both groups '{taken[member]}' and '{group}'")
                taken[member] = group
                row[index[member]] = 1.0
            rows.append(row)
        rest = [name for name in class_names if name not in taken]
        for name in rest:
            row = np.zeros(len(class_names), dtype=np.float32)
            row[index[name]] = 1.0
            rows.append(row)
        if len(rows) > 255:
            raise InputError(f"{len(rows)} labels do not fit the uint8 label maps")
        return cls(
            names=tuple(spec),
            members=tuple(tuple(m) for m in spec.values()),
            label_names=tuple(spec) + tuple(rest),
            matrix=np.stack(rows),
        )

    @property
    def n_groups(self) -> int:
        return len(self.names)

    def group(self, probs: np.ndarray) -> np.ndarray:
        """(C, h, w) model probabilities -> (S, h, w) grouped probabilities; the first G are the groups."""
        c, h, w = probs.shape
        flat = probs.reshape(c, h * w)
        out = np.empty((len(self.matrix), h * w), dtype=flat.dtype)
        # Element-wise sums of the members, not a BLAS product: the same bits at any BLAS thread count.
        single_rows, single_classes, multi = self._layout
        out[single_rows] = flat[single_classes]
        for s, members in multi:
            out[s] = flat[members].sum(axis=0)
        return out.reshape(-1, h, w)

    @functools.cached_property
    def _layout(self) -> tuple[np.ndarray, np.ndarray, list[tuple[int, np.ndarray]]]:
        """Rows that copy one model class (row, class), and rows that sum several (row, classes)."""
        members = [np.flatnonzero(row) for row in self.matrix]
        single = [(s, m[0]) for s, m in enumerate(members) if len(m) == 1]
        multi = [(s, m) for s, m in enumerate(members) if len(m) > 1]
        rows, classes = (np.array(v, dtype=np.int64) for v in zip(*single)) if single else (np.zeros(0, np.int64),) * 2
        return rows, classes, multi

    def spec(self) -> dict[str, list[str]]:
        return {name: list(members) for name, members in zip(self.names, self.members)}
