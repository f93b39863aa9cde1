"""How much each cue counts, earned on the stream: how often its answer lands where its own trajectory said it would.

Every cue (LoST-X, the layout, appearance: :mod:`lostx.core.match.combined`) runs a sequence filter of its own over
its scores alone (:mod:`lostx.core.route.sequence`). Before frame t arrives, that filter's best trajectory predicts
where the frame's answer lies: its position at frame t - 1 plus its speed. The cue's single-frame answer at t *agrees*
when it lands within ``e`` (``cues.agree_within``) map frames of the prediction. A cue that sees the places of this map
from this stream agrees often, whatever it is: its answers follow the motion. One that is noise here (a layout that
cannot see its grid, an appearance that does not survive the turn to the other end of the road, a mirrored
verification on a road that looks the same both ways) lands there about as often as a map frame drawn at random:

    chance = (2 e + 1) / N                       N: map frames
    rate   = a / n, at the lower bound of its one-sided 95 % Wilson interval
                                                 a agreements in n predictions, forgetting with a memory of 2 L
                                                 frames (L: the window's length)
    w      = max(0, (rate - chance) / (1 - chance))

Every cue starts with no weight and earns it as its agreement is shown (a lucky first frame is not); until any has,
the answer is LoST-X's, the method the others join (:class:`lostx.core.match.combined.CombinedScores`). The test is causal and not
self-confirming: a prediction is made from frames before t, and judged by frame t's own answer, which played no part
in it. The same test on the cues' combined answer, under each heading, tells the headings apart by which one's answers
keep to their trajectory (:mod:`lostx.core.route.heading`), and says when the motion and the matches disagree
(:class:`Disagreement`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .sequence import SequenceFilter, SequenceResult


def agrees(answer: int, previous: SequenceResult | None, within: float) -> bool | None:
    """Whether ``answer`` lies within ``within`` map frames of where ``previous`` (the best trajectory at the frame
    before) predicts the next answer: its position plus its speed. None where there is no prediction."""
    if previous is None or not np.isfinite(previous.position) or not np.isfinite(previous.speed):
        return None
    return bool(abs(float(answer) - (previous.position + previous.speed)) <= within)


def chance(n_frames: int, within: float) -> float:
    """How often an answer drawn at random from a map of ``n_frames`` lands within ``within`` of a prediction."""
    return float(min(1.0, (2.0 * np.floor(within) + 1.0) / max(n_frames, 1)))


SURE = 1.645
"""Standard errors below its measured rate that a cue's agreement is counted at: the lower bound of its one-sided 95 %
Wilson interval."""


@dataclass
class Tally:
    """Agreements and predictions, each forgetting with ``memory`` frames."""

    memory: float
    agreed: float = 0.0
    predicted: float = 0.0

    def add(self, agreed: bool | None) -> None:
        if agreed is None:
            return
        keep = 1.0 - 1.0 / self.memory
        self.agreed = keep * self.agreed + float(agreed)
        self.predicted = keep * self.predicted + 1.0

    def weight(self, at_chance: float) -> float:
        """w = max(0, (rate - chance) / (1 - chance)), the rate the lower bound of its Wilson interval (:data:`SURE`
        standard errors down): a cue counts as far as its agreement is shown, not as far as a lucky first frame says."""
        if at_chance >= 1.0 or self.predicted <= 0.0:
            return 0.0
        n, z = self.predicted, SURE
        p = self.agreed / n
        centre = p + z * z / (2 * n)
        spread = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
        low = (centre - spread) / (1 + z * z / n)
        return max(0.0, (low - at_chance) / (1.0 - at_chance))

    def state(self) -> list[float]:
        return [self.agreed, self.predicted]

    def restore(self, state: list[float]) -> None:
        self.agreed, self.predicted = float(state[0]), float(state[1])


class CueAgreement:
    """One cue's own sequence filter and how often its answers agree with it."""

    def __init__(self, make_filter: Callable[[], SequenceFilter], memory: float, within: float) -> None:
        self.filter = make_filter()
        self.tally = Tally(memory)
        self.within = within
        self.last: SequenceResult | None = None
        """The filter's best trajectory after the latest frame: the next frame's prediction."""
        self.agreed: bool | None = None
        """Whether the latest frame's answer agreed (None: there was no prediction)."""

    def update(self, scores, answer: int, candidates: np.ndarray, seeds: np.ndarray | None,  # noqa: ANN001
               progress: float | None) -> bool | None:
        """Add one frame: the cue's scores of the map frames (lower is better), its answer, the candidates and
        seeds its filter anchors trajectories at, and the frame's progress (following the distance travelled)."""
        self.agreed = agrees(answer, self.last, self.within)
        self.tally.add(self.agreed)
        self.last = self.filter.update(scores, candidates, seeds, None, progress)
        return self.agreed

    def weight(self, n_frames: int) -> float:
        return self.tally.weight(chance(n_frames, self.within))

    def state(self) -> dict:
        last = self.last
        return {"filter": self.filter.state(), "tally": self.tally.state(), "agreed": self.agreed,
                "last": None if last is None else [last.position, last.speed, last.score, last.frames,
                                                   last.trajectory, last.mean]}

    def restore(self, state: dict) -> None:
        self.filter.restore(state["filter"])
        self.tally.restore(state["tally"])
        self.agreed = state["agreed"]
        last = state["last"]
        self.last = None if last is None else SequenceResult(float(last[0]), float(last[1]), float(last[2]),
                                                             int(last[3]), np.asarray(last[4]), float(last[5]))


class Disagreement:
    """Whether the motion and the matches disagree: of the answers of the last ``FRAMES`` frames that had a
    prediction, fewer than ``NEEDED`` landed on the answering trajectory's line. Either the line is not what the frames
    show (a bend it cuts, a map that does not hold the road, a misled cue) or the frames' own answers are noise it
    rightly ignores: the answer says so, and a user (or a planner) weighs it."""

    FRAMES = 8
    NEEDED = 2

    def __init__(self) -> None:
        self.recent: deque[bool] = deque(maxlen=self.FRAMES)

    def add(self, agreed: bool | None) -> None:
        if agreed is not None:
            self.recent.append(agreed)

    @property
    def disagree(self) -> bool:
        return len(self.recent) >= self.FRAMES // 2 and sum(self.recent) < self.NEEDED

    def reset(self) -> None:
        self.recent.clear()

    def state(self) -> list[bool]:
        return list(self.recent)

    def restore(self, state: list[bool]) -> None:
        self.recent = deque((bool(v) for v in state), maxlen=self.FRAMES)
