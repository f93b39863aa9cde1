"""`lostx ros2` against a ROS 2 peer on Fast DDS (rmw_fastrtps' middleware), on loopback.

Builds scripts/fastdds_peer.cpp (needs g++ and Fast DDS 2.x: `apt-get install libfastrtps-dev libfastcdr-dev`),
maps the RobotCar day frames with positions 2 m apart, starts `lostx ros2` on that map, and has the Fast DDS peer
publish the ten night frames as CompressedImage, one at a time, and decode every Place and pose lostx answers with
(Fast CDR on both ends). Each answer must be the one `lostx match --sequence` gives the same frames. A probe frame
goes first, sent again until answered (see fastdds_peer.cpp: the first message of a new Fast DDS writer does not
always reach Cyclone DDS), and says how many it took.

    python scripts/check_fastdds.py [--work DIR]
"""

from __future__ import annotations

import argparse
import csv
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
WINDOW = "3"
TOPIC = "/camera/image_raw/compressed"


def robotcar() -> Path:
    from lostx.core.paths import data_dir

    return data_dir() / "robotcar-daynight"


def lostx(*args: object) -> list[str]:
    return [sys.executable, "-m", "lostx.cli", *map(str, args)]


def fast_dds_missing() -> str | None:
    """Why the peer cannot be built here, or None."""
    if shutil.which("g++") is None:
        return "no C++ compiler (g++)"
    if not Path("/usr/include/fastdds/dds/domain/DomainParticipant.hpp").is_file():
        return "Fast DDS is not installed (apt-get install libfastrtps-dev libfastcdr-dev)"
    return None


def build_peer(work: Path) -> Path:
    peer = work / "fastdds_peer"
    subprocess.run(["g++", "-std=c++17", "-O1", "-o", str(peer), str(HERE / "fastdds_peer.cpp"), "-lfastrtps",
                    "-lfastcdr"], check=True)
    return peer


def positioned_map(work: Path) -> Path:
    """The day frames' map, with positions 2 m apart along x (so that lostx publishes poses too)."""
    day = robotcar() / "day"
    files = sorted(p.name for p in day.glob("*.png"))
    (work / "positions.csv").write_text("file,x,y\n" + "".join(f"{f},{2.0 * k},5.0\n" for k, f in enumerate(files)))
    out = work / "day.map"
    subprocess.run(lostx("map", "build", day, "--positions", work / "positions.csv", "--out", out, "--quiet",
                         "--overwrite"), check=True, capture_output=True)
    return out


def run(work: Path) -> dict:
    """Everything the check found: lostx match's rows, the peer's places and poses, the node's last line."""
    peer, refmap = build_peer(work), positioned_map(work)
    night = sorted((robotcar() / "night").glob("*.png"))
    subprocess.run(lostx("match", refmap, robotcar() / "night", "--sequence", "--window", WINDOW, "--out",
                         work / "match.csv", "--quiet"), check=True, capture_output=True)
    with open(work / "match.csv") as handle:
        rows = list(csv.DictReader(handle))
    domain = random.SystemRandom().randrange(100, 200)
    log = open(work / "node.log", "w")
    env = {k: v for k, v in os.environ.items() if k != "CYCLONEDDS_URI"}
    node = subprocess.Popen(lostx("ros2", "--map", refmap, "--topic", TOPIC, "--window", WINDOW, "--image-qos",
                                  "reliable", "--domain-id", domain), stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        end = time.monotonic() + 120
        while "answering" not in (work / "node.log").read_text():
            if node.poll() is not None or time.monotonic() > end:
                raise RuntimeError(f"lostx ros2 did not start:\n{(work / 'node.log').read_text()}")
            time.sleep(0.2)
        player = subprocess.Popen([str(peer), str(domain), "120", *map(str, night)], stdin=subprocess.PIPE,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        if player.stdout.readline().strip() == "matched":
            found = [f"{TOPIC}: 1 publisher", "/lostx/place: 1 subscriber", "/lostx/pose: 1 subscriber"]
            while not all(f in (work / "node.log").read_text() for f in found) and time.monotonic() < end:
                time.sleep(0.05)
        stdout, stderr = player.communicate("go\n", timeout=600)
        out = subprocess.CompletedProcess(player.args, player.returncode, stdout, stderr)
    finally:
        node.send_signal(signal.SIGINT)
        node.wait(30)
        log.close()
    if out.returncode != 0:
        raise RuntimeError(f"the Fast DDS peer failed: {out.stderr}{out.stdout}\nlostx ros2:\n"
                           f"{(work / 'node.log').read_text()}")
    places = [dict(re.findall(r"(\w+)=(\S*)", line)) for line in out.stdout.splitlines() if line.startswith("place")]
    poses = [dict(re.findall(r"(\w+)=(\S*)", line)) for line in out.stdout.splitlines() if line.startswith("pose")]
    summary = [line for line in (work / "node.log").read_text().splitlines() if "answered" in line]
    probes = int(re.search(r"probes (\d+)", out.stdout).group(1))
    return {"rows": rows, "places": places, "poses": poses, "node": summary[-1] if summary else "", "probes": probes}


def differences(found: dict) -> list[str]:
    """What the peer received that is not what lostx match says, or is missing."""
    rows, places, poses = found["rows"], found["places"], found["poses"]
    out = []
    if len(places) != len(rows) or len(poses) != len(rows):
        out.append(f"{len(places)} places and {len(poses)} poses for {len(rows)} frames")
    for row, place in zip(rows, places):  # the frames are numbered after the probes: compared in order
        got = (place["state"], place["match"], place["name"])
        want = (row["state"], row["match_index"], row["match_file"])
        if got != want or place["stream"] != TOPIC:
            out.append(f"frame {row['query_index']}: Fast DDS got {got}, lostx match says {want}")
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path,
                        help="folder for the peer, the map and the logs (default: a temporary one)")
    args = parser.parse_args()
    missing = fast_dds_missing()
    if missing is not None:
        print(f"check_fastdds: cannot build the Fast DDS peer: {missing}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="lostx-fastdds-") as tmp:
        work = args.work or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        found = run(work)
    for place, pose in zip(found["places"], found["poses"]):
        print(f"frame {place['frame']}: {place['state']}, map frame {place['match']} ({place['name']}), "
              f"pose x={pose['x']} y={pose['y']} in {pose['frame_id']}")
    print(found["node"])
    wrong = differences(found)
    for line in wrong:
        print(f"DIFFERS: {line}")
    print(f"Fast DDS peer: {len(found['places'])} of {len(found['rows'])} answers, "
          f"{'all' if not wrong else 'not all'} equal to lostx match; the first message took "
          f"{found['probes']} probe{'s' if found['probes'] > 1 else ''} to get through")
    return 1 if wrong else 0


if __name__ == "__main__":
    sys.exit(main())
