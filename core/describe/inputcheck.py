"""What a map's frames looked like when it was built, and a warning when live frames clearly differ.

A map records the size of its frames, whether they were colour or greyscale,
how bright they were and, for LoST maps, how often the network gave each
semantic label. A localizer compares every query frame with that record and
warns once for each kind of clear difference (64 x 32 greyscale thumbnails
against a map of 1024 x 640 colour street scenes, a covered lens, a scene the
network labels nothing like the map's). The answers are computed all the same:
a warning says that they may not mean much.

Night queries against a day map are what the method is for: brightness warns
only for frames that are almost black or almost white when no map frame was.
"""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass
from typing import Any, Iterable, Sequence

import numpy as np

SIZE_FACTOR = 4.0
"""A frame with this many times more, or fewer, pixels than every map frame is of another camera."""
ASPECT_TOLERANCE = 0.25
"""... as is one whose width / height is off by more than this fraction of every map frame's."""
GREY_LEVEL = 2.0
"""A frame whose channels differ by less than this (mean |R - G| + mean |G - B|, grey levels) is greyscale."""
COLOUR_MAJORITY = 0.95
"""The map is colour (greyscale) when at least this fraction of its frames are."""
DARK, BRIGHT = 10.0, 245.0
"""Mean brightness (0-255) of an almost black and an almost white frame."""
LABEL_FRAMES = 5
"""Query frames whose labels are pooled before they are compared with the map's."""
LABEL_DISTANCE = 0.4
"""Total variation distance between the query's and the map's label frequencies that is clearly another
kind of scene (measured with MOSAIC: RobotCar night against day 0.11; Nordland 64 x 32 against RobotCar 0.49-0.60)."""
SAMPLE_SIDE = 64
"""Pixels sampled along a frame's longer side (enough for averages: 0.06 ms for a 1024 x 640 frame)."""
CHECK_FIRST, CHECK_EVERY = 10, 25
"""Every one of the first frames is checked, then one in this many (input rarely changes kind mid-stream)."""


class InputWarning(UserWarning):
    """Query frames that do not look like the frames the map was built from."""


@dataclass(frozen=True)
class InputProfile:
    """What a map's frames looked like (stored in the map's manifest under ``input``)."""

    width: tuple[int, int]
    """Smallest and largest frame width, pixels."""
    height: tuple[int, int]
    greyscale: float | None
    """Fraction of the frames that were greyscale (of those neither almost black nor almost white;
    None when every frame was)."""
    brightness: tuple[float, float]
    """Mean brightness (0-255) of the darkest and of the brightest frame."""
    labels: dict[str, float] | None = None
    """LoST maps: how often the network gave each label (grouped label space, in its order)."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> "InputProfile | None":
        """The profile of a manifest's ``input`` entry; None for maps built before profiles were kept."""
        if not data:
            return None
        return cls(width=tuple(data["width"]), height=tuple(data["height"]), greyscale=data["greyscale"],
                   brightness=tuple(data["brightness"]), labels=data.get("labels"))


@dataclass(frozen=True)
class Looks:
    """The few things about one frame that the check compares."""

    width: int
    height: int
    greyscale: bool | None
    """None: too dark or too bright to tell."""
    brightness: float


def looks(image: np.ndarray) -> Looks:
    """Size, greyscale and mean brightness of an H x W x 3 uint8 frame, from a sparse sample of its pixels."""
    step = max(1, max(image.shape[:2]) // SAMPLE_SIDE)
    sample = image[::step, ::step].astype(np.float32)
    spread = float(np.abs(sample[..., 0] - sample[..., 1]).mean() + np.abs(sample[..., 1] - sample[..., 2]).mean())
    brightness = float(sample.mean())
    return Looks(width=int(image.shape[1]), height=int(image.shape[0]),
                 greyscale=spread < GREY_LEVEL if DARK <= brightness <= BRIGHT else None, brightness=brightness)


def label_frequencies(labels: np.ndarray, n_labels: int) -> np.ndarray:
    """How often each label occurs in a label map, as fractions summing to 1."""
    counts = np.bincount(np.asarray(labels, dtype=np.int64).ravel(), minlength=n_labels)[:n_labels]
    return counts / max(int(counts.sum()), 1)


class ProfileBuilder:
    """Collects :func:`looks` (and label frequencies) of the frames of a map being built."""

    def __init__(self, label_names: Sequence[str] | None = None) -> None:
        self.label_names = list(label_names) if label_names is not None else None
        self._looks: list[Looks] = []
        self._labels = np.zeros(len(self.label_names or ()))

    def add(self, image: np.ndarray, labels: np.ndarray | None = None) -> None:
        frequencies = label_frequencies(labels, len(self.label_names)) if self.label_names is not None and \
            labels is not None else None
        self.add_looks(looks(image), frequencies)

    def add_looks(self, frame: Looks, frequencies: np.ndarray | None = None) -> None:
        """Add a frame by what it looked like (and its label frequencies)."""
        self._looks.append(frame)
        if self.label_names is not None and frequencies is not None:
            self._labels += frequencies

    def profile(self) -> InputProfile | None:
        if not self._looks:
            return None
        widths = [x.width for x in self._looks]
        heights = [x.height for x in self._looks]
        bright = [x.brightness for x in self._looks]
        known = [x.greyscale for x in self._looks if x.greyscale is not None]
        labels = None
        if self.label_names is not None:
            mean = self._labels / len(self._looks)
            labels = {name: round(float(v), 6) for name, v in zip(self.label_names, mean)}
        return InputProfile(width=(min(widths), max(widths)), height=(min(heights), max(heights)),
                            greyscale=float(np.mean(known)) if known else None,
                            brightness=(round(min(bright), 3), round(max(bright), 3)), labels=labels)


def size_difference(frame: Looks, profile: InputProfile) -> str | None:
    pixels = frame.width * frame.height
    fewest, most = profile.width[0] * profile.height[0], profile.width[1] * profile.height[1]
    aspect = frame.width / frame.height
    narrowest, widest = profile.width[0] / profile.height[1], profile.width[1] / profile.height[0]
    if (pixels * SIZE_FACTOR < fewest or pixels > most * SIZE_FACTOR
            or aspect < narrowest * (1 - ASPECT_TOLERANCE) or aspect > widest * (1 + ASPECT_TOLERANCE)):
        sizes = " to ".join(dict.fromkeys(f"{w} x {h}" for w, h in zip(profile.width, profile.height)))
        return f"{frame.width} x {frame.height} pixels (the map's frames: {sizes})"
    return None


def colour_difference(frame: Looks, profile: InputProfile) -> str | None:
    if frame.greyscale is None or profile.greyscale is None:
        return None
    if frame.greyscale and profile.greyscale <= 1 - COLOUR_MAJORITY:
        return "greyscale (the map's frames: colour)"
    if not frame.greyscale and profile.greyscale >= COLOUR_MAJORITY:
        return "in colour (the map's frames: greyscale)"
    return None


def brightness_difference(frame: Looks, profile: InputProfile) -> str | None:
    darkest, brightest = profile.brightness
    if frame.brightness < DARK <= darkest:
        return f"almost black (mean brightness {frame.brightness:.0f} of 255; the map's darkest frame: {darkest:.0f})"
    if frame.brightness > BRIGHT >= brightest:
        return (f"almost white (mean brightness {frame.brightness:.0f} of 255; "
                f"the map's brightest frame: {brightest:.0f})")
    return None


def label_difference(query: np.ndarray, profile: InputProfile) -> str | None:
    """Pooled query label frequencies (in the map's label order) clearly unlike the map's."""
    names = list(profile.labels or {})
    reference = np.array(list((profile.labels or {}).values()))
    if not names or len(query) != len(reference):
        return None
    if 0.5 * float(np.abs(query - reference).sum()) <= LABEL_DISTANCE:
        return None

    def top(freq: np.ndarray) -> str:
        return ", ".join(f"{names[i]} {100 * freq[i]:.0f} %" for i in np.argsort(-freq)[:3])

    return f"the network finds {top(query)}, against {top(reference)} in the map's frames"


class InputCheck:
    """Warns (:class:`InputWarning`) once for each kind of clear difference between query frames and the map's."""

    def __init__(self, profile: InputProfile | None) -> None:
        self.profile = profile
        self.reported: set[str] = set()
        n_labels = len(profile.labels) if profile is not None and profile.labels else 0
        self._label_sum = np.zeros(n_labels)
        self._label_frames = 0
        self._first_label_frame = 0
        self._seen = 0

    @classmethod
    def for_map(cls, manifest: dict[str, Any]) -> "InputCheck":
        return cls(InputProfile.from_dict(manifest.get("input")))

    @property
    def compares_labels(self) -> bool:
        """The map records how often the network gave each label, and the query's labels are compared with it."""
        return len(self._label_sum) > 0

    def __call__(self, frame_id: int, image: np.ndarray, labels: np.ndarray | None = None) -> None:
        self._seen += 1
        if self.profile is None or len(self.reported) == 4:
            return
        if self._seen > CHECK_FIRST and self._seen % CHECK_EVERY:
            return
        frame = looks(image)
        found = {}
        for kind, test in (("size", size_difference), ("colour", colour_difference),
                           ("brightness", brightness_difference)):
            text = None if kind in self.reported else test(frame, self.profile)
            if text:
                found[kind] = text
        if found:
            self._warn(found.keys(), f"frame {frame_id} is {'; '.join(found.values())}")
        if labels is not None and len(self._label_sum) and "labels" not in self.reported:
            if not self._label_frames:
                self._first_label_frame = frame_id
            self._label_sum += label_frequencies(labels, len(self._label_sum))
            self._label_frames += 1
            if self._label_frames >= LABEL_FRAMES:
                text = label_difference(self._label_sum / self._label_frames, self.profile)
                if text:
                    self._warn(["labels"], f"in frames {self._first_label_frame} to {frame_id} {text}")

    def _warn(self, kinds: Iterable[str], text: str) -> None:
        self.reported.update(kinds)
        warnings.warn(f"{text}: not what the map was built from, so its answers may not mean much",
                      InputWarning, stacklevel=4)
