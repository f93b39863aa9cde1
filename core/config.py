"""All tunable settings, in one typed place, with defaults that work.

A :class:`Config` is made of one frozen dataclass per stage. Build one in
Python (``Config()``, ``dataclasses.replace``), or load overrides from a TOML
file whose tables are named after the sections::

    [verify]
    scoring = "released"
    top_k = 20

Unknown keys are an error, so a typo never silently falls back to a default,
and every number is checked against its valid range (:data:`LIMITS`) whenever
a :class:`Config` is made, however it is made.
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from .errors import InputError
from .frame import CAMERAS

Scoring = Literal["eq4-lost", "eq4", "released"]
Fit = Literal["squash", "crop", "pad"]
DensityFilter = Literal["query", "both", "off"]
Normalisation = Literal["running", "reference"]
StreamMode = Literal["live", "lossless"]
IndexUse = Literal["auto", "on", "off"]
CostsUse = Literal["auto", "every", "looked-up"]
LayoutUse = Literal["auto", "on", "off"]
MotionSource = Literal["auto", "odometry", "visual"]
WarmUp = Literal["sequence", "single"]
Reliability = Literal["best_effort", "reliable"]
Durability = Literal["volatile", "transient_local"]
CUES: tuple[str, ...] = ("lostx", "layout", "appearance")
"""The single-frame cues (lostx.core.match.combined), in the order their weights are reported."""


@dataclass(frozen=True)
class BackboneConfig:
    """Which semantic segmentation network describes the frames."""

    name: str = "mosaic-ade20k"
    """Backbone name (``lostx backbones`` lists them), a plugin's name, or ``package.module:factory``."""
    model_path: Path | None = None
    """Model file (for ``tflite`` and ``onnx``: the model's TOML description, or the model with it beside);
    ``None`` looks in the models folder (``$LOSTX_MODELS`` or ``../shared/models``)."""
    device: str = "auto"
    """``auto`` (a CUDA GPU where the runtime has one, else the CPU), ``cpu``, ``cuda`` or ``cuda:N``, for the
    PyTorch and ONNX backbones; TFLite backbones run on the CPU."""
    threads: int = 2
    """CPU threads for inference."""
    fit: Fit = "squash"
    """How a frame is fitted to the network input's aspect ratio: resized as it is (``squash``), its
    centre cut out (``crop``), or black borders added (``pad``). A map records it; queries follow the map."""


@dataclass(frozen=True)
class CameraConfig:
    """The vehicle's cameras, by the direction they face (``front``, ``rear``), brought to a common geometry
    before the network (lostx.core.describe.camera). A frame takes the settings of the camera it declares; a frame
    that declares none is taken as it is."""

    hfov_deg: dict[str, float] = field(default_factory=dict)
    """Each camera's horizontal field of view in degrees, e.g. ``{front = 65.1, rear = 90.2}``."""
    view_hfov_deg: float | None = None
    """Building a map: narrow every frame to this common field of view (the map records it, and queries
    from a wider camera are narrowed to it)."""
    ignore_top: dict[str, float] = field(default_factory=dict)
    """Fraction of each camera's frame height dropped at the top."""
    ignore_bottom: dict[str, float] = field(default_factory=dict)
    """Fraction of each camera's frame height dropped at the bottom (the vehicle's own bonnet or boot lid),
    e.g. ``{rear = 0.08}``."""


@dataclass(frozen=True)
class LostConfig:
    """The LoST descriptor (paper Eq. 1-3) and its normalisation."""

    classes: dict[str, tuple[str, ...]] | None = None
    """Semantic classes of the descriptor: name -> the model's class names it groups.
    ``None`` uses ``class_preset``, else the backbone's own default (road, building, vegetation)."""
    class_preset: str | None = None
    """Descriptor classes by name: ``street`` (road, building, vegetation) or ``indoor`` (wall, floor,
    ceiling), as groups of whatever the model calls them. ``classes``, when given, is used instead."""
    coverage_frames: int = 5
    """The first this many frames of a map build or a stream are checked for class coverage."""
    coverage_warning: float = 0.2
    """Warn (once) when the descriptor's classes label less than this share of those frames' feature grids."""
    reference_window: int = 15
    """Class means mu_s of a map frame are averaged over this many frames centred on it."""
    query_window: int = 1
    """Class means of a live query are averaged over it and the previous frames (never future ones)."""
    normalisation: Normalisation = "running"
    """Per-dimension standardisation of query descriptors: ``reference`` uses the map's
    statistics; ``running`` starts from them and updates with the queries seen so far."""
    prior_frames: float = 1.0
    """Weight, in frames, of the map's statistics in the running normalisation."""


@dataclass(frozen=True)
class VerifyConfig:
    """Candidate search and spatial layout verification (paper Sec. III-A/C)."""

    enabled: bool = True
    """Verify the candidates' spatial layout (LoST-X); ``False`` ranks by the LoST descriptor alone
    (the paper's "LoST" baseline)."""
    top_k: int = 10
    """Candidates passed from the descriptor search to verification."""
    scoring: Scoring = "eq4-lost"
    """``eq4``: r_c of Eq. 4. ``eq4-lost``: r_c times the LoST cosine distance.
    ``released``: the scoring of the authors' released code."""
    density_filter: DensityFilter = "query"
    """3x3 neighbourhood density test in the query image, in both images, or off."""
    uniqueness_exclusion: int = 2
    """Confidence compares the best score with the best candidate more than this many
    reference frames away from it."""
    reduce_above: int = 512
    """A map built from features of more channels than this keeps its keypoint descriptors as ``reduced_dim``
    coordinates on a projection learnt from its own descriptors (lostx.core.describe.reduce), and verification
    compares them there: wide or dense features cost little and take few bytes. Narrower features (MOSAIC's
    448, ESPNetv2's 512) are kept whole and exact. Read when a map is built; the map records the projection."""
    reduced_dim: int = 64
    """Dimensions the keypoint descriptors of a wide backbone are reduced to (see ``reduce_above``)."""


@dataclass(frozen=True)
class SearchConfig:
    """How the nearest map frames of a query descriptor are found: compared with every map frame, or
    through the approximate index built with the map (see lostx.core.match.search)."""

    index: IndexUse = "auto"
    """``auto``: the index for maps of at least ``index_min_frames`` frames, every frame compared below;
    ``on``: the index whatever the size (the map must have one); ``off``: every frame compared."""
    index_min_frames: int = 20000
    """Map size from which ``auto`` searches the index (below it comparing every frame is fast enough)."""
    index_breadth: int = 64
    """How much of the index's graph a search explores (its candidate list): wider finds the exact
    nearest more often and takes longer."""
    index_shortlist: int = 40
    """Map frames taken from the index per search and ranked again by their exact distance."""


@dataclass(frozen=True)
class SequenceConfig:
    """Online sequence filter over a rolling window of frames (see lostx.core.route.sequence)."""

    enabled: bool = True
    """Answer with the sequence filter (``False``: single-frame answers)."""
    length: int = 20
    """L: frames in the rolling window."""
    speeds: tuple[float, ...] = (0.25, 0.5, 0.75, 0.8, 0.9, 1.0, 1.1, 1.2, 1.25, 1.5, 1.75, 2.0)
    """Trajectory slopes the search may use, in reference frames per query frame, each with both signs
    (a falling reference index: the mapped route driven the other way), and 0 (stopped). With a
    track, the tracker picks those within its plausible band."""
    acquire_speeds: tuple[float, ...] = (0.8, 0.9, 1.0, 1.1, 1.2)
    """Slopes searched without a track (OpenSeqSLAM's range), each with both signs: a stopped or slow
    vehicle is only plausible once the tracker has seen it slow down."""
    costs: CostsUse = "auto"
    """Where the trajectories' costs are computed: ``every`` map frame for every frame (a step costs
    O(map size)); ``looked-up``: only where the filter looks, around its trajectories and the ``nearest``
    map frames of each search (a step costs the same whatever the map size); ``auto``: looked up for maps
    of at least ``costs_min_frames`` frames."""
    costs_min_frames: int = 500000
    """Map size from which ``auto`` looks costs up (below it computing them all is as fast)."""
    anchors: int = 20
    """Trajectories are anchored at each frame's verified candidates and its this many lowest-cost references
    over the map (where costs are looked up: its ``nearest`` lowest among those where the live trajectories pass and
    around the ``nearest`` map frames of its search)."""
    nearest: int = 40
    """Where costs are looked up: map frames nearest to a frame's descriptor around which (each with its
    ``contrast_window`` neighbourhood) its anchors are looked for, and how many anchors it gives."""
    hypotheses: int = 500
    """Where costs are looked up: at most this many live trajectories, each followed while the frames' anchors keep
    falling on it (a new anchor on a live trajectory supports it instead of starting a copy), so that a step's work
    is bounded by the anchors, the window and the speeds, not by the map (lostx.core.route.sequence)."""
    radius: int = 0
    """A trajectory takes a frame's lowest cost within this many reference frames of its line."""
    contrast_window: int = 10
    """References around each one that its cost is normalised against (SeqSLAM's contrast enhancement); near an end
    of the map, as many nearest that end (lostx.core.match.costs.neighbourhoods)."""
    contrast_distance: float = 60.0
    """Following the distance travelled: the references of this many metres of the map's route (at its median
    frame spacing) are the neighbourhood instead. A layout match spreads over some 20 m of road, whatever the frame
    rate: a narrower neighbourhood takes the depth of a true match's broad valley for noise."""
    reference_prior: float = 100.0
    """Weight, in frames, of the prior in each reference's running cost statistics (hub suppression)."""
    penalty: float = 0.0
    """Cost of a trajectory point off the map, or of a frame without costs (0 = an average reference)."""
    switch_cost: float = 8.0
    """J: what a trajectory that enters the map within the window pays, in the costs' standard deviations, for its
    frames before it (they then count at the lowest sum any trajectory had over them, not as average ones);
    ``inf``: they count as average ones, as SeqSLAM. A vehicle coming onto the mapped stretch from outside it is
    followed once its trajectory has out-scored the look-alike that led meanwhile by J, not once the look-alike's
    frames have left the window. 8: the lowest cost that changes no figure where the queries start on the map, in
    any variant of the opposite-view study (with 4, a weaker layout's answers jump to the map's far end:
    docs/opposite-view.md, Entering the map)."""
    exclusion: int = 5
    """Confidence compares the best trajectory with the best one ending more than this many
    reference frames away."""
    distance_window: float = 45.0
    """Following the distance travelled: the window holds the frames of the last this many metres (at most
    ``length`` of them, ``distance_window / length`` metres apart but for the newest), so that its reach does not
    depend on the frame rate or the speed."""
    distance_ratios: tuple[float, ...] = (0.8, 0.9, 1.0, 1.1, 1.25)
    """Following the distance travelled: metres along the map per metre travelled, each with both signs (the
    route driven the other way): 1 where both odometries agree, the others absorb their scale errors."""
    direction_reliability: float = 0.65
    """Where nothing ties the direction of travel to the heading (no declared camera, no motion): how often one
    frame's vote (its best falling trajectory against its best rising one) points the right way; the answer
    follows the direction found once it is ``heading.min_confidence`` probable (see lostx.core.route.direction)."""
    direction_scale: float = 1.0
    """Difference of the two directions' best mean costs (in the costs' standard deviations) that makes a full
    vote; smaller differences vote in proportion."""
    warm_up: WarmUp = "sequence"
    """The answer while the window fills (``warming_up``, never ``localized``): ``sequence``, the best trajectory
    over the frames so far (measured better than the single frame on every data set here but one, see
    docs/metrics.md); ``single``, the frame's own single-frame answer."""


def looks_up_costs(config: SequenceConfig, n_frames: int) -> bool:
    """Whether a sequence filter with these settings looks its costs up on a map of ``n_frames``."""
    return config.costs == "looked-up" or (config.costs == "auto" and n_frames >= config.costs_min_frames)


@dataclass(frozen=True)
class LayoutConfig:
    """The layout of a place on a bird's-eye grid, from a calibrated camera and its motion (see
    lostx.core.layout): compared turned 180 degrees, it recognises a road seen from its other end."""

    enabled: LayoutUse = "auto"
    """``auto``: where the frames carry a camera geometry (a dataset's calibration, a bag's camera info, a
    camera file) and the model has a road class; ``on``: required (an error where it cannot be); ``off``."""
    cell: float = 2.0
    """Side of a grid cell, metres."""
    length: float = 40.0
    """Metres of road along the camera's axis the grid covers."""
    width: float = 30.0
    """Metres across."""
    centre: float = 15.0
    """The grid's centre, metres ahead of the camera along its axis."""
    max_range: float = 60.0
    """Rays landing further from the camera than this are not used (their ground points are too coarse)."""
    blur: float = 1.0
    """Standard deviation of the smoothing, metres."""
    query_travel: float = 24.0
    """A live frame's grid gathers the frames of the last this many metres travelled (never future ones)."""
    map_travel: float = 18.0
    """A map frame's grid gathers the frames within this many metres travelled on either side of it."""
    max_frames: int = 12
    """At most this many frames are gathered into one grid (the most recent ones, or those nearest a map frame)."""
    across_shift: float = 4.0
    """The grids are compared shifted sideways up to this many metres: a car driving the road the other way drives
    another lane, 3 to 3.7 m over (benchmarks/study_layout.py judges it over the lane and one to either side)."""
    vehicle_weight: float = 0.5
    """Weight of the vehicles' channel against the others' 1: parked cars come and go between visits."""
    min_cells: int = 25
    """Cells both grids must observe for a comparison to count."""


@dataclass(frozen=True)
class CuesConfig:
    """The single-frame cues (LoST-X, the layout, appearance) and how much each counts (see
    lostx.core.match.combined and lostx.core.route.agreement)."""

    appearance: bool = True
    """Appearance (GeM pooling of the network's features) takes part as a cue where the map holds its descriptors."""
    weights: dict[str, float] = field(default_factory=dict)
    """Fixed weights by cue (``lostx``, ``layout``, ``appearance``), for comparisons; empty: each cue's weight is what
    it earns on the stream, how often its answer lands where its own trajectory predicted."""
    agree_within: float = 3.0
    """Map frames within which a cue's answer counts as landing where its trajectory predicted it."""


@dataclass(frozen=True)
class MotionConfig:
    """How the camera's motion between frames is known (see lostx.core.motion)."""

    source: MotionSource = "auto"
    """``auto``: the source's odometry where frames carry it, else visual odometry on the frames; ``odometry``:
    only the source's (frames without none have no motion); ``visual``: always from the frames."""
    visual_width: int = 800
    """Frames are resized to this width for visual odometry."""


@dataclass(frozen=True)
class DecisionConfig:
    """When an answer is ``localized``: its confidence, calibrated on the map (see lostx.core.decide.calibration)."""

    min_confidence: float = 0.999
    """An answer is ``localized`` when its confidence is at least this: when the wrong answers the map produces
    against itself lead their runner-up by as much with a probability of at most 1 - this (0.999: one in a
    thousand), as the fitted tail of their leads says."""
    calibration_frames: int = 2000
    """Map frames matched against the map (their neighbourhood excluded) to measure wrong answers;
    longer maps are sampled in stretches spread over the route."""


@dataclass(frozen=True)
class HeadingConfig:
    """Which way the queries view the route relative to the map: found from the evidence, a declared
    camera direction being a prior (see lostx.core.route.heading)."""

    declared_prior: float = 0.5
    """Probability given, before any evidence, to the heading a declared camera implies for a vehicle
    driving the map's direction (a front camera on a front-camera map: ``same``). 0.5 assumes nothing
    about the direction of travel (the declared camera then only ties that direction to the heading
    found); 0.9 for a vehicle known to drive the mapped direction; 1.0 trusts the declaration outright."""
    misled: float = 0.05
    """How likely any one voter is to be misled by a road, pointing the wrong way however consistently (a street that
    looks alike both ways, a turn where neither heading holds): a sure voter moves the heading's odds by at most
    (1 - misled) / misled, and voters that disagree leave it uncertain (see lostx.core.route.heading). Chosen across
    both nuScenes scenes for the heading's calibration (benchmarks/study_heading.py)."""
    switch: float = 0.0003
    """Probability per frame that the heading changes (the vehicle turned round, another camera): the votes are
    forgotten over 1 / switch frames."""
    min_confidence: float = 0.9
    """A sequence answer is ``localized`` only when its heading is at least this probable."""


@dataclass(frozen=True)
class TrackerConfig:
    """Recursive filter over route position and speed (see lostx.core.route.tracker)."""

    enabled: bool = True
    gate_sigma: float = 4.0
    """Answers further than this many innovation standard deviations from the prediction are implausible."""
    agree_within: float = 1.0
    """A confident answer is ``localized`` only within this many reference frames of the track's prediction: one
    that is plausible but further has changed the track's speed or position by more than the map resolves, and is
    trusted again once the two agree."""
    relocalise_after: int = 3
    """Consecutive implausible, confident and mutually consistent answers that restart the track
    (a genuine jump: a kidnapped vehicle, a gap in the map)."""
    acquire_after: int = 5
    """Consecutive mutually consistent answers that start a track without a confident one (a short map rarely
    makes one confident); 0: only a confident answer starts a track. Such a track answers where the sequence
    filter jumps, but trusts nothing by itself: ``localized`` still needs the confidence. Only while the
    trajectories follow the frames: their test is a constant speed in map frames per frame, which stops and
    changes of speed break when they follow the distance (there it cost 10 of 32 opposite-view queries)."""
    lost_after: int = 10
    """Consecutive implausible answers after which the track is dropped and must be acquired again."""
    position_sigma: float = 2.0
    """Measurement noise of a sequence answer, in reference frames."""
    speed_sigma: float = 0.1
    """Initial uncertainty of the speed, in reference frames per frame (a wide initial speed band
    lets slow trajectories on look-alike references in right after a track starts)."""
    acceleration_sigma: float = 0.05
    """Process noise: how fast the speed may change, per frame."""


@dataclass(frozen=True)
class StreamConfig:
    """The ZeroMQ service: endpoints, flow control and the limits a peer's messages must keep
    (docs/protocol.md explains each). Read by lostx.stream only; core never opens a socket."""

    frames: str = "tcp://127.0.0.1:5555"
    """Where the service binds the frames socket (ROUTER); producers connect here."""
    results: str = "tcp://127.0.0.1:5556"
    """Where the service binds the results socket (XPUB); listeners connect here."""
    mode: StreamMode = "live"
    """``live``: always work on the newest frame, count the others as dropped.
    ``lossless``: answer every frame in order and hold producers back instead."""
    window: int = 4
    """Lossless: frames a producer may have sent and not yet had answered (its credit)."""
    queue: int = 16
    """Lossless: frames the service holds before it stops reading the socket (a safety net
    behind the window for producers that ignore credit)."""
    wait_listeners: int = 0
    """Hold producers back until this many listeners have subscribed to results."""
    max_message_bytes: int = 16 * 1024 * 1024
    """A message above this is answered with a ``too_large`` error; above twice this the
    transport drops the connection before reading it."""
    max_pixels: int = 4096 * 4096
    """Frames declaring more pixels are refused before anything is decoded."""
    frame_hwm: int = 16
    """ZeroMQ high-water mark (messages) of the frames socket."""
    result_hwm: int = 1000
    """ZeroMQ high-water mark (messages) per listener on the results socket."""
    pending_results: int = 64
    """Lossless: outgoing messages held for a slow listener before the localizer pauses."""
    stats_interval: float = 1.0
    """Seconds between stats (heartbeat) messages."""
    linger: float = 2.0
    """Seconds the service spends flushing results on exit."""
    history: str = ""
    """Where the service binds the history socket (ROUTER) from which listeners fetch journaled
    answers; empty: the results endpoint with its port plus one (tcp) or ``-history`` appended."""
    journal: Path | None = None
    """Folder of the result journal: every answer is written there before its frame is acknowledged,
    and listeners resume from it. ``None``: no journal."""
    journal_segment_bytes: int = 16 * 1024 * 1024
    """The journal starts a new segment file when the current one reaches this size."""
    journal_max_bytes: int = 256 * 1024 * 1024
    """The journal deletes its oldest segments to stay within this size."""
    journal_fsync: bool = True
    """Flush each batch of answers to the disk (fsync) before acknowledging the frames; ``False``
    survives a crash of the service but not of the machine."""
    max_streams: int = 64
    """Streams with a state (a localizer each) at one time; a frame of one more is refused."""
    max_streams_per_peer: int = 8
    """Streams one producer (one connection) may hold, so that one cannot take every slot; a producer
    at its limit that starts another stream gives up its least recently used idle one."""
    stream_expiry: float = 300.0
    """Seconds without a frame after which a stream's state is forgotten (its next frame starts afresh)."""
    max_time_jump: float = 3600.0
    """Seconds a frame's timestamp may jump ahead of its stream's previous one; further ahead is refused.
    A jump back by more than this starts a new traverse (a restarted clock); less is refused."""


@dataclass(frozen=True)
class Ros2Config:
    """``lostx ros2``: the topics it reads and writes over DDS as ROS 2 nodes do (docs/ros2.md explains each).
    Read by lostx.stream.ros2 only."""

    domain_id: int | None = None
    """The ROS domain (DDS domain id); None: ``$ROS_DOMAIN_ID``, else 0."""
    interface: str = "loopback"
    """The network interface DDS uses: ``loopback`` (this machine only), an interface's name or address (other
    machines on that network), or ``auto`` (Cyclone DDS chooses)."""
    namespace: str = "/lostx"
    """The answers are published on ``<namespace>/place`` and ``<namespace>/pose``."""
    map_frame: str = "map"
    """The ``frame_id`` of the published poses: the map's positions are in this frame."""
    image_reliability: Reliability = "best_effort"
    """Images: ``best_effort`` (ROS's sensor-data profile) takes frames from any publisher; ``reliable`` asks
    a reliable publisher for every frame."""
    image_depth: int = 5
    """Images held for the localizer, per camera topic; with ``image_reliability = "reliable"``, 0 keeps every
    image (keep all: a reliable publisher is held back until the localizer has taken each one)."""
    odometry_reliability: Reliability = "best_effort"
    """Odometry: ``best_effort`` takes it from any publisher; ``reliable`` only from reliable ones, and misses none."""
    answer_reliability: Reliability = "reliable"
    answer_durability: Durability = "volatile"
    """``transient_local``: a subscriber that joins late gets the last ``answer_depth`` answers."""
    answer_depth: int = 10
    """Answers kept for each subscriber (keep last: a subscriber that stalls loses the oldest, and never holds
    up the localizer)."""
    odometry_wait: float = 0.1
    """Seconds a frame waits for an odometry message stamped at or after it (to interpolate the motion)."""
    camera_info_wait: float = 0.05
    """Seconds a frame waits for the camera info stamped as it is (else the latest camera info is used)."""
    max_extrapolation: float = 0.5
    """Seconds past its newest odometry message a frame's pose is extrapolated; further, the frame has none."""


@dataclass(frozen=True)
class Config:
    """Everything lostx can be tuned by."""

    backbone: BackboneConfig = field(default_factory=BackboneConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    lost: LostConfig = field(default_factory=LostConfig)
    verify: VerifyConfig = field(default_factory=VerifyConfig)
    search: SearchConfig = field(default_factory=SearchConfig)
    sequence: SequenceConfig = field(default_factory=SequenceConfig)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    heading: HeadingConfig = field(default_factory=HeadingConfig)
    layout: LayoutConfig = field(default_factory=LayoutConfig)
    cues: CuesConfig = field(default_factory=CuesConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    decision: DecisionConfig = field(default_factory=DecisionConfig)
    stream: StreamConfig = field(default_factory=StreamConfig)
    ros2: Ros2Config = field(default_factory=Ros2Config)

    def __post_init__(self) -> None:
        check_config(self)

    def to_dict(self) -> dict[str, Any]:
        return _plain(dataclasses.asdict(self))


@dataclass(frozen=True)
class Bounds:
    """The valid values of a number (or of each number of a list, which must not be empty)."""

    low: float | None = None
    high: float | None = None
    above: bool = False
    """``low`` itself is not allowed."""

    def describe(self) -> str:
        if self.low is None:
            return "a number" if self.high is None else f"at most {self.high:g}"
        if self.high is not None:
            return f"above {self.low:g}, at most {self.high:g}" if self.above else f"between {self.low:g} and {self.high:g}"
        return f"above {self.low:g}" if self.above else f"at least {self.low:g}"

    def allows(self, value: float) -> bool:
        if math.isnan(value):
            return False
        if self.low is not None and (value < self.low or (self.above and value == self.low)):
            return False
        return self.high is None or value <= self.high


_AT_LEAST_0, _AT_LEAST_1, _ABOVE_0 = Bounds(0), Bounds(1), Bounds(0, above=True)

LIMITS: dict[str, dict[str, Bounds]] = {
    "backbone": {"threads": Bounds(1, 256)},
    "lost": {
        "coverage_frames": _AT_LEAST_0, "coverage_warning": Bounds(0, 1), "reference_window": _AT_LEAST_1,
        "query_window": _AT_LEAST_1, "prior_frames": _AT_LEAST_0,
    },
    "verify": {"top_k": _AT_LEAST_1, "uniqueness_exclusion": _AT_LEAST_0, "reduce_above": _AT_LEAST_1,
               "reduced_dim": Bounds(1, 4096)},
    "search": {"index_min_frames": _AT_LEAST_1, "index_breadth": Bounds(1, 4096), "index_shortlist": Bounds(1, 4096)},
    "camera": {"hfov_deg": Bounds(0, 180, above=True), "view_hfov_deg": Bounds(0, 180, above=True),
               "ignore_top": Bounds(0, 0.9), "ignore_bottom": Bounds(0, 0.9)},
    "sequence": {
        "length": Bounds(1, 100_000), "speeds": _AT_LEAST_0, "acquire_speeds": _ABOVE_0, "anchors": _AT_LEAST_0,
        "hypotheses": _AT_LEAST_1, "nearest": _AT_LEAST_0,
        "costs_min_frames": _AT_LEAST_1,
        "radius": _AT_LEAST_0, "contrast_window": Bounds(2), "contrast_distance": _ABOVE_0,
        "reference_prior": _AT_LEAST_0,
        "penalty": Bounds(), "switch_cost": _AT_LEAST_0, "exclusion": _AT_LEAST_0, "distance_window": _ABOVE_0,
        "distance_ratios": _ABOVE_0,
        "direction_reliability": Bounds(0.5, 0.999), "direction_scale": _ABOVE_0,
    },
    "layout": {
        "cell": Bounds(0.1, 10), "length": Bounds(1, 200), "width": Bounds(1, 200), "centre": Bounds(0, 200),
        "max_range": _ABOVE_0, "blur": Bounds(0, 20), "query_travel": _AT_LEAST_0, "map_travel": _AT_LEAST_0,
        "max_frames": Bounds(1, 200), "across_shift": Bounds(0, 20), "vehicle_weight": Bounds(0, 1),
        "min_cells": _AT_LEAST_1,
    },
    "cues": {"weights": _AT_LEAST_0, "agree_within": _AT_LEAST_0},
    "motion": {"visual_width": Bounds(64, 8192)},
    "heading": {"declared_prior": Bounds(0.5, 1), "misled": Bounds(0, 0.5, above=True), "switch": Bounds(0, 0.5),
                "min_confidence": Bounds(0.5, 1)},
    "decision": {"min_confidence": Bounds(0, 1), "calibration_frames": _AT_LEAST_1},
    "tracker": {
        "gate_sigma": _ABOVE_0, "agree_within": _AT_LEAST_0, "relocalise_after": _AT_LEAST_1,
        "acquire_after": _AT_LEAST_0, "lost_after": _AT_LEAST_1,
        "position_sigma": _ABOVE_0, "speed_sigma": _ABOVE_0, "acceleration_sigma": _ABOVE_0,
    },
    "stream": {
        "window": _AT_LEAST_1, "queue": _AT_LEAST_1, "wait_listeners": _AT_LEAST_0, "max_message_bytes": _AT_LEAST_1,
        "max_pixels": _AT_LEAST_1, "frame_hwm": _AT_LEAST_0, "result_hwm": _AT_LEAST_0,
        "pending_results": _AT_LEAST_1, "stats_interval": _ABOVE_0, "linger": _AT_LEAST_0,
        "journal_segment_bytes": _AT_LEAST_1, "journal_max_bytes": _AT_LEAST_1, "max_streams": Bounds(1, 256),
        "max_streams_per_peer": Bounds(1, 256), "stream_expiry": _ABOVE_0, "max_time_jump": _ABOVE_0,
    },
    "ros2": {
        "domain_id": Bounds(0, 232), "image_depth": Bounds(0, 10_000), "answer_depth": Bounds(1, 10_000),
        "odometry_wait": _AT_LEAST_0, "camera_info_wait": _AT_LEAST_0, "max_extrapolation": _AT_LEAST_0,
    },
}
"""Valid values of every numeric setting, by section and key (docs/config.md lists them)."""


def check_config(config: Config) -> None:
    """Raise :class:`InputError` naming the first setting outside its valid values."""
    for section, rules in LIMITS.items():
        values = getattr(config, section)
        for key, bounds in rules.items():
            value = getattr(values, key, None)
            if value is None:
                continue  # no such setting (any more): tests/test_config.py keeps LIMITS in step with the sections
            if isinstance(value, tuple) and not value:
                raise InputError(f"[{section}] {key} must not be empty")
            if isinstance(value, dict):
                names, what = (CUES, "cue") if (section, key) == ("cues", "weights") else (CAMERAS, "camera")
                unknown = sorted(set(value) - set(names))
                if unknown:
                    raise InputError(f"[{section}] {key}: unknown {what} {unknown[0]!r}; {what}s: {', '.join(names)}")
            items = value.values() if isinstance(value, dict) else value if isinstance(value, tuple) else (value,)
            for item in items:
                if not bounds.allows(item):
                    raise InputError(f"[{section}] {key} must be {bounds.describe()}, got {item!r}")


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def config_from_dict(data: dict[str, Any], base: Config | None = None, source: str = "config") -> Config:
    """Apply a nested mapping of overrides onto ``base`` (default: all defaults)."""
    base = base or Config()
    sections: dict[str, Any] = {}
    hints = typing.get_type_hints(Config)
    for name, values in data.items():
        if name not in hints:
            raise InputError(f"{source}: unknown section [{name}]; known: {', '.join(hints)}")
        if not isinstance(values, dict):
            raise InputError(f"{source}: [{name}] must be a table of settings")
        sections[name] = _section(getattr(base, name), values, f"{source} [{name}]")
    try:
        return dataclasses.replace(base, **sections)
    except InputError as exc:
        raise InputError(f"{source}: {exc}") from None


def _section(current: Any, values: dict[str, Any], where: str) -> Any:
    hints = typing.get_type_hints(type(current))
    changes: dict[str, Any] = {}
    for key, value in values.items():
        if key not in hints:
            raise InputError(f"{where}: unknown setting '{key}'; known: {', '.join(hints)}")
        changes[key] = _coerce(value, hints[key], f"{where} {key}")
    return dataclasses.replace(current, **changes)


def _coerce(value: Any, hint: Any, where: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Union or origin is getattr(__import__("types"), "UnionType", None):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _coerce(value, inner[0], where)
    if origin is Literal:
        if value not in args:
            raise InputError(f"{where}: {value!r} is not one of {', '.join(map(repr, args))}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise InputError(f"{where}: expected a list, got {value!r}")
        return tuple(_coerce(v, args[0], where) for v in value)
    if origin is dict:
        if not isinstance(value, dict):
            raise InputError(f"{where}: expected a table, got {value!r}")
        return {str(k): _coerce(v, args[1], where) for k, v in value.items()}
    if hint is Path:
        return Path(value)
    if hint is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if hint in (int, str, bool) and type(value) is hint:
        return value
    raise InputError(f"{where}: expected {getattr(hint, '__name__', hint)}, got {value!r}")


def load_config(path: str | Path | None, base: Config | None = None) -> Config:
    """Read overrides from a TOML file; ``None`` gives ``base`` or the defaults."""
    if path is None:
        return base or Config()
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise InputError(f"config file not found: {path}") from None
    except IsADirectoryError:
        raise InputError(f"config file {path} is a folder: give the TOML file of settings in it "
                         f"(see docs/config.md)") from None
    except OSError as exc:
        raise InputError(f"config file {path} cannot be read ({exc.strerror or exc})") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    return config_from_dict(data, base, source=str(path))
