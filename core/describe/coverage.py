"""Are the descriptor's classes in the frames at all? LoST describes a place by its classes: road, building
and vegetation say little about a corridor. The first frames of a map build or a stream are checked once.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..backbones.presets import PRESETS, preset_classes
from ..errors import InputError


class ClassCoverageWarning(UserWarning):
    """The descriptor's classes label little of the frames."""


def covered_share(shares: np.ndarray, class_names: Sequence[str], groups: dict[str, tuple[str, ...]]) -> float:
    """The share of the grid whose label is one of the groups' classes, given each model class's share."""
    members = {name for names in groups.values() for name in names}
    return float(sum(share for name, share in zip(class_names, shares) if name in members))


def coverage_message(shares: np.ndarray, class_names: Sequence[str], groups: dict[str, tuple[str, ...]],
                     frames: int, threshold: float) -> str | None:
    """The one-line warning when the groups cover less than ``threshold`` of the grid, else None.

    ``shares`` is each model class's share of the labels over the first ``frames`` frames.
    """
    covered = covered_share(shares, class_names, groups)
    if covered >= threshold:
        return None
    members = {name for names in groups.values() for name in names}
    order = [i for i in np.argsort(-shares, kind="stable") if class_names[i] not in members and shares[i] > 0]
    dominant = ", ".join(f"{class_names[i]} {shares[i]:.0%}" for i in order[:3])
    better = []
    for preset in PRESETS:
        try:
            share = covered_share(shares, class_names, preset_classes(preset, class_names))
        except InputError:
            continue  # the model has no class for one of the preset's groups
        if share >= threshold and share > covered:
            better.append((share, preset))
    presets = ", ".join(f"--class-preset {name} (covers {share:.0%})" for share, name in sorted(better, reverse=True))
    way = f"e.g. {presets}, or" if presets else "with"
    return (
        f"the descriptor's classes ({', '.join(groups)}) label {covered:.0%} of the first {frames} frames "
        f"(warning below {threshold:.0%}); the frames are mostly {dominant or 'unlabelled'}: name classes they "
        f"show, {way} [lost] classes in a --config file (docs/backbones.md)"
    )


class CoverageCheck:
    """Counts the model's labels over the first frames and gives the warning once, if it is due."""

    def __init__(self, class_names: Sequence[str], groups: dict[str, tuple[str, ...]], frames: int,
                 threshold: float) -> None:
        self.class_names = tuple(class_names)
        self.groups = groups
        self.frames = frames
        self.threshold = threshold
        self._counts = np.zeros(len(self.class_names), dtype=np.int64)
        self._seen = 0

    @property
    def done(self) -> bool:
        return self._seen >= self.frames

    def add(self, labels: np.ndarray) -> str | None:
        """Count one frame's (h, w) model labels; the warning after the last checked frame, if due."""
        if self.done:
            return None
        self._counts += np.bincount(labels.ravel(), minlength=len(self.class_names))[: len(self.class_names)]
        self._seen += 1
        if not self.done:
            return None
        shares = self._counts / max(int(self._counts.sum()), 1)
        return coverage_message(shares, self.class_names, self.groups, self.frames, self.threshold)
