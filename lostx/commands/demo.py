"""``lostx demo``: the whole streaming loop on one machine, on the RobotCar day/night pair.

It builds (or reuses) the day map, starts ``lostx serve`` on it, listens to the
service's answers, and starts ``lostx replay`` on the night frames as a live
stream; it prints each answer as it arrives and a summary against the index
ground truth. With ``--web`` the service keeps serving the web viewer after the
summary, until Ctrl-C. Every process it starts is stopped on the way out (also
on Ctrl-C and on errors).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING

from lostx.display import state_label, window_note
from lostx.options import (
    VIEWER_NOTICE,
    add_backbone_options,
    add_viewer_options,
    config_from_args,
    number,
    viewer_args,
    window_length,
)

if TYPE_CHECKING:
    from lostx.core.config import Config
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.stream.client import Listener
    from lostx.stream.processes import ProcessGroup
    from lostx.stream.messages import Result, Stats


def register(sub: argparse._SubParsersAction) -> None:
    parser = sub.add_parser("demo", help="map the RobotCar day frames, localize the night frames")
    parser.add_argument("--data", type=Path, help="folder holding robotcar-daynight/ (default ../shared/data)")
    parser.add_argument("--workdir", type=Path, help="where the demo keeps its map (default ~/.cache/lostx/demo)")
    parser.add_argument("--rebuild", action="store_true", help="rebuild the map even if one is there")
    parser.add_argument("--rate", type=number(0, above=True), default=4.0, metavar="HZ",
                        help="replay rate of the night frames (default 4; a slower localizer holds the replay back)")
    parser.add_argument("--window", type=window_length, default=3, metavar="L",
                        help="sequence window in frames (default 3: the sample traverse has only 10 frames)")
    add_backbone_options(parser)
    add_viewer_options(parser)
    parser.set_defaults(run=run)


def demo_map(day: Path, out: Path, config: Config, rebuild: bool) -> ReferenceMap:
    """The day map, reused when one built by the same backbone and descriptor classes from the same folder is
    there."""
    from lostx.core.backbones import load_backbone
    from lostx.core.build import build_map
    from lostx.core.describe.describer import LostDescriber
    from lostx.core.errors import MapError
    from lostx.core.maps.refmap import ReferenceMap
    from lostx.replay.folder import folder_traverse

    backbone = load_backbone(config.backbone)
    describer = LostDescriber(backbone, config.lost)
    if not rebuild and (out / "manifest.json").is_file():
        try:
            refmap = ReferenceMap.open(out)
            refmap.check_backbone(backbone.info)
            manifest = refmap.manifest
            if manifest.get("image_root") == str(day.resolve()) and manifest.get("classes") == describer.groups.spec():
                print(f"reusing the map in {out}")
                return refmap
        except MapError:
            pass
    traverse = folder_traverse(day)
    summary = build_map(traverse, out, config, describer,
                        {"camera": "front", "image_root": str(day.resolve())}, overwrite=True, total=len(traverse),
                        label="describing the day frames")
    print(f"built {summary.path}: {summary.n_frames} frames, {summary.bytes_per_frame / 1e3:.1f} kB per frame")
    return ReferenceMap.open(out)


def run(args: argparse.Namespace) -> int:
    from lostx.core.errors import InputError
    from lostx.core.outputs import check_output_folder
    from lostx.core.paths import cache_dir, data_dir
    from lostx.replay.folder import folder_traverse
    from lostx.stream.processes import ProcessGroup

    config = config_from_args(args)
    data = (args.data or data_dir()) / "robotcar-daynight"
    if not (data / "day").is_dir() or not (data / "night").is_dir():
        raise InputError(f"demo data not found: {data} should hold day/ and night/ (pass --data or set LOSTX_DATA)")
    workdir = check_output_folder(args.workdir or cache_dir() / "demo", "--workdir")
    night = folder_traverse(data / "night")
    note = window_note(args.window, len(night), data / "night")
    if note is not None:
        print(note, flush=True)
    refmap = demo_map(data / "day", workdir / f"robotcar-day-{config.backbone.name}", config, args.rebuild)
    # Every stop signal ends the demo like Ctrl-C does, through the cleanup below (lostx.cli).
    with tempfile.TemporaryDirectory(prefix="lostx-demo-") as tmp, ProcessGroup(log_dir=tmp) as procs:
        notices = _ViewerNotices(procs)
        answers, final = _stream(args, refmap, night, Path(tmp), procs, notices)
        _summary(answers, len(night), final, _too_short(refmap, config))
        if args.web:
            _keep_serving(procs, notices)
    return 0


def _backbone_args(args: argparse.Namespace) -> list[str]:
    out: list[str] = []
    for option in ("backbone", "model", "device", "threads"):
        value = getattr(args, option, None)
        if value is not None:
            out += [f"--{option}", str(value)]
    return out


class _ViewerNotices:
    """Repeats the service's lines about the live view (its web viewer's URL, a viewer that cannot
    start), which would otherwise stay in its log."""

    def __init__(self, procs: ProcessGroup) -> None:
        self.procs = procs
        self.said: set[str] = set()
        self.web_url: str | None = None

    def echo(self) -> None:
        for line in self.procs.log("serve").splitlines():
            if line.startswith(VIEWER_NOTICE) and line not in self.said:
                self.said.add(line)
                print(line, flush=True)
                if " web viewer at " in line:
                    self.web_url = line.split(" web viewer at ", 1)[1].split()[0]


def _keep_serving(procs: ProcessGroup, notices: _ViewerNotices) -> None:
    """The summary is out: keep the service (and its web viewer) up until Ctrl-C."""
    notices.echo()
    if notices.web_url is None:
        return
    print(f"{VIEWER_NOTICE}serving the web viewer at {notices.web_url} until Ctrl-C", flush=True)
    try:
        while procs.processes["serve"].poll() is None:
            time.sleep(0.5)
    except KeyboardInterrupt:
        return
    print(f"{VIEWER_NOTICE}the service ended (code {procs.processes['serve'].returncode}); no more web viewer")


def _stream(args: argparse.Namespace, refmap: ReferenceMap, night, tmp: Path, procs: ProcessGroup,
            notices: _ViewerNotices) -> tuple[dict[int, Result], Stats | None]:
    """Service, listener (this process) and replay: the answers by frame id, and the service's stats
    (its final ones; with ``--web`` the service stays up, and they are its latest).

    The service runs lossless: on a loaded machine a slower localizer holds the replay back instead of
    dropping frames, so every night frame is answered. It keeps no journal (``--no-journal``): its one
    listener is this process, subscribed before the first frame and there until the last answer."""
    from lostx.stream.client import Listener
    from lostx.stream.errors import StreamError
    from lostx.stream.processes import lostx_command
    from lostx.stream.messages import ErrorMessage, Result, Stats

    frames, results = f"ipc://{tmp}/frames", f"ipc://{tmp}/results"
    last_id = len(night) - 1
    answers: dict[int, Result] = {}
    final: Stats | None = None
    with Listener(results) as listener:
        # The service waits for this listener before it takes frames, so no answer is missed.
        procs.start("serve", lostx_command("serve", "--map", str(refmap.path), "--frames", frames,
                                           "--results", results, "--mode", "lossless", "--no-journal",
                                           "--wait-listeners", "1",
                                           "--window", str(args.window), *_backbone_args(args),
                                           *viewer_args(args)))
        procs.start("replay", lostx_command("replay", str(night.root), "--to", frames, "--rate", str(args.rate),
                                            "--quiet", "--wait", "60"))
        print(f"\nservice on {refmap.path.name}, replaying {len(night)} night frames at {args.rate:g} Hz "
              f"(lossless: every frame is answered)")
        print(f"\n{'query':>14s}  {'truth':>5s}  {'match':>5s}  {'single':>6s}  {'state':>13s}  {'conf':>5s}  "
              f"{'corr':>4s}")
        deadline = time.monotonic() + 120
        while last_id not in answers:
            message = listener.receive(0.5)
            notices.echo()
            if isinstance(message, Result):
                answers[message.frame_id] = message
                print(_row(message, night, refmap), flush=True)
            elif isinstance(message, ErrorMessage):
                print(f"frame {message.frame_id}: error {message.code}: {message.text}")
            for name in ("serve", "replay"):
                code = procs.processes[name].poll()
                if code not in (None, 0):
                    raise StreamError(f"lostx {name} exited with code {code}:\n{procs.log(name).strip()}")
            if time.monotonic() > deadline:
                raise StreamError("the service did not answer the last frame within 120 s:\n" + procs.log("serve"))
        # Lossless answers come in order, so once the last frame is answered all are.
        if args.web:
            return answers, _next_stats(listener)
        code = procs.stop("serve")
        while final is None:
            message = listener.receive(2.0)
            if message is None:
                break
            if isinstance(message, Stats) and message.final:
                final = message
        if code != 0:
            raise StreamError(f"lostx serve exited with code {code}:\n{procs.log('serve').strip()}")
    return answers, final


def _next_stats(listener: Listener, timeout: float = 5.0) -> Stats | None:
    """The service's next stats message (sent every second), counting every answer so far."""
    from lostx.stream.messages import Stats

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        message = listener.receive(0.5)
        if isinstance(message, Stats):
            return message
    return None


def _row(r: Result, night, refmap: ReferenceMap) -> str:
    corr = r.candidates[0].correspondences if r.candidates else 0
    state = state_label(r)
    return (f"{night.names[r.frame_id]:>14s}  {r.frame_id:>5d}  {r.match_index:>5d}  {r.single_match_index:>6d}  "
            f"{state:>13s}  {r.confidence:5.2f}  {corr:4d}  {_mark(r.match_index, r.frame_id)}")


def _mark(match: int, truth: int) -> str:
    return "exact" if match == truth else ("+-1" if abs(match - truth) == 1 else "wrong")


def _too_short(refmap: ReferenceMap, config: Config) -> str | None:
    """Why the service's answers could not be ``localized`` on this map, from the calibration it stored beside it."""
    from lostx.core.decide.calibration import load

    calibration = load(refmap.path, config)
    return None if calibration is None else calibration.too_short(True, config.decision.min_confidence)


def _summary(answers: dict[int, Result], n_frames: int, final: Stats | None, too_short: str | None = None) -> None:
    import numpy as np

    truth = np.array(list(answers))
    n = len(answers)

    def counts(found: np.ndarray) -> str:
        return f"{int((found == truth).sum())}/{n} exact, {int((np.abs(found - truth) <= 1).sum())}/{n} within one frame"

    sequence = np.array([r.match_index for r in answers.values()])
    single = np.array([r.single_match_index for r in answers.values()])
    localized = sum(r.state == "localized" for r in answers.values())
    print(f"\nnight -> day (answered {n} of {n_frames}):")
    print(f"  sequence filter:  {counts(sequence)}; {localized} localized")
    if too_short:
        print(f"                    ({too_short})")
    print(f"  single frame:     {counts(single)}")
    print("  the authors' LoST-X on the same frames (single frame): 6/10 exact, 8/10 within one frame")
    if final is not None:
        step = final.latency_ms.get("step", {})
        service = final.latency_ms.get("service", {})
        if "p50" in step and "p50" in service:
            print(f"latency: localizer {step['p50']:.0f} ms, frame read -> answer published {service['p50']:.0f} ms "
                  f"(medians)")
