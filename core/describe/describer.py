"""From a frame to what LoST-X needs of it: class probabilities, labels, class means, keypoints."""

from __future__ import annotations

import warnings
from collections import deque
from dataclasses import dataclass

import numpy as np

from ..backbones import Backbone, BackboneInfo, SemanticFrame
from ..backbones.presets import preset_classes
from ..config import LostConfig
from ..errors import InputError, ModelError
from .classes import ClassGroups
from .coverage import ClassCoverageWarning, CoverageCheck
from .keypoints import KeypointEvidence, frame_evidence
from .lost import class_means, gem_pool, lost_descriptor, window_means


@dataclass
class DescribedFrame:
    """One frame through the backbone, before its class means are chosen."""

    features: np.ndarray  # (D, N) float32: x_i
    group_probs: np.ndarray  # (G, N): m_is of the descriptor classes
    labels: np.ndarray  # (h, w) uint8: l_i in the grouped label space (Eq. 3)
    means: np.ndarray  # (G, D): this frame's own mu_s (Eq. 2)
    present: np.ndarray  # (G,) bool: class s occurs in the frame
    evidence: KeypointEvidence
    label_map: np.ndarray | None = None
    """The model's own label map of the frame (:attr:`SemanticFrame.label_map`), for the layout."""

    def appearance(self) -> np.ndarray:
        """(D,) GeM-pooled features: the appearance baseline (computed on request, not in the live path)."""
        return gem_pool(self.features)


class LostDescriber:
    """Runs the backbone and computes the frame-local parts of LoST and the keypoints."""

    def __init__(self, backbone: Backbone, config: LostConfig | None = None) -> None:
        self.backbone = backbone
        self.config = config or LostConfig()
        info = backbone.info
        self.groups = ClassGroups.from_spec(descriptor_classes(self.config, info), info.class_names)
        if self.config.reference_window < 1 or self.config.query_window < 1:
            raise InputError("class-mean windows must be at least 1 frame")
        if self.config.coverage_frames < 0 or not 0.0 <= self.config.coverage_warning <= 1.0:
            raise InputError("[lost] coverage_frames must be 0 or more and coverage_warning between 0 and 1")
        self.coverage = CoverageCheck(info.class_names, self.groups.spec(), self.config.coverage_frames,
                                      self.config.coverage_warning)

    def __call__(self, image: np.ndarray) -> DescribedFrame:
        return self.from_semantic(self.backbone(image))

    def from_semantic(self, semantic: SemanticFrame) -> DescribedFrame:
        check_semantic(semantic, self.backbone.info)
        if not self.coverage.done:
            message = self.coverage.add(semantic.labels())
            if message:
                warnings.warn(message, ClassCoverageWarning, stacklevel=2)
        d, h, w = semantic.features.shape
        features = semantic.features.reshape(d, h * w)
        grouped = self.groups.group(semantic.probs).reshape(-1, h * w)
        labels = grouped.argmax(axis=0).astype(np.uint8)  # Eq. 3
        g = self.groups.n_groups
        if not np.isfinite(features).all() or not np.isfinite(grouped).all():
            raise InputError("the backbone produced non-finite features or probabilities for this frame")
        means, present = class_means(features, labels, g)
        return DescribedFrame(
            features=features,
            group_probs=grouped[:g],
            labels=labels.reshape(h, w),
            means=means,
            present=present,
            evidence=frame_evidence(semantic.features, labels.reshape(h, w)),
            label_map=semantic.label_map,
        )

    def descriptor(self, frame: DescribedFrame, means: np.ndarray) -> np.ndarray:
        """Eq. 1 with the chosen class means (the frame's own, or a window's)."""
        return lost_descriptor(frame.features, frame.group_probs, means)


def descriptor_classes(config: LostConfig, info: BackboneInfo) -> dict[str, tuple[str, ...]]:
    """The descriptor's classes: the configured groups, else the configured preset, else the backbone's default."""
    if config.classes:
        return config.classes
    if config.class_preset:
        return preset_classes(config.class_preset, info.class_names)
    return info.default_classes


def check_semantic(semantic: SemanticFrame, info: BackboneInfo) -> None:
    """A backbone's output must have the shapes its info promises (a map holds those)."""
    grid = tuple(info.grid)
    expected = ((info.feature_dim, *grid), (len(info.class_names), *grid))
    if (semantic.features.shape, semantic.probs.shape) != expected:
        raise ModelError(
            f"backbone {info.name} gave features {_dims(semantic.features.shape)} and probabilities "
            f"{_dims(semantic.probs.shape)}, but its info promises {_dims(expected[0])} and {_dims(expected[1])}"
        )


def _dims(shape: tuple[int, ...]) -> str:
    return " x ".join(map(str, shape))


class TrailingMeans:
    """Class means of a live query averaged over it and up to ``window - 1`` previous frames."""

    def __init__(self, window: int) -> None:
        self._recent: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=window)

    def reset(self) -> None:
        self._recent.clear()

    def __call__(self, frame: DescribedFrame) -> np.ndarray:
        self._recent.append((frame.means, frame.present))
        mus = np.stack([m for m, _ in self._recent])
        present = np.stack([p for _, p in self._recent])
        return window_means(mus, present)[0]

    def state(self) -> dict:
        return {"recent": [[means, present] for means, present in self._recent]}

    def restore(self, state: dict) -> None:
        self._recent.clear()
        self._recent.extend((np.asarray(m), np.asarray(p)) for m, p in state["recent"])
