"""A ROS 2 peer for the tests, written apart from lostx: Cyclone DDS types made from the ROS 2 message
definitions (the interfaces' ``.msg`` text, lostx's ``Place`` from the ``.msg`` files it ships), a publisher
that replays a bag over DDS as ``ros2 bag play`` would, and a subscriber that collects answers.

Nothing here imports lostx's own ROS 2 types: what lostx sends must decode with these, and what these send
must reach lostx. Run as a script, it is the publisher process:

    python tests/ros2tools.py publish BAG --domain N [--lockstep NS] [--topic-map FROM=TO]
"""

from __future__ import annotations

import argparse
import os
import random
import sys
import time
import types
import uuid
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path
from typing import Any

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bagtools import MESSAGES, TYPES  # noqa: E402 (the ROS 2 interfaces' definitions, as the bags store them)

LOSTX_MSGS = HERE.parent / "stream" / "ros2" / "interfaces" / "lostx_msgs" / "msg"
EXTRA = {
    "geometry_msgs/msg/PoseWithCovarianceStamped": "std_msgs/Header header\ngeometry_msgs/PoseWithCovariance pose",
}
PRIMITIVES = {
    "bool": bool, "byte": t.byte, "char": t.uint8, "int8": t.int8, "uint8": t.uint8, "int16": t.int16,
    "uint16": t.uint16, "int32": t.int32, "uint32": t.uint32, "int64": t.int64, "uint64": t.uint64,
    "float32": t.float32, "float64": t.float64, "string": str,
}
LOOPBACK = ('<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface address="127.0.0.1" '
            'multicast="true"/></Interfaces></General><Discovery><ParticipantIndex>auto</ParticipantIndex>'
            '<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex><Peers><Peer address="localhost"/></Peers>'
            '</Discovery></Domain></CycloneDDS>')
"""This machine only, found by multicast on the loopback interface and by unicast to localhost."""


def definitions() -> dict[str, str]:
    """Every message definition used, by full name (``pkg/msg/Name``)."""
    out = {name.replace("/", "/msg/", 1): text for name, text in TYPES.items()}
    out.update({name: text for name, (text, _) in MESSAGES.items()})
    out.update(EXTRA)
    for path in LOSTX_MSGS.glob("*.msg"):
        out[f"lostx_msgs/msg/{path.stem}"] = path.read_text()
    return out


class Types:
    """Cyclone DDS types made from ``.msg`` definitions, named as ROS 2's middlewares name them."""

    def __init__(self) -> None:
        self.text = definitions()
        self.made: dict[str, type] = {}

    def __getitem__(self, name: str) -> type:
        if name not in self.made:
            self.made[name] = self._make(name)
        return self.made[name]

    def _make(self, name: str) -> type:
        package, _, short = name.split("/")
        annotations: dict[str, Any] = {}
        for line in self.text[name].splitlines():
            line = line.split("#", 1)[0].strip()
            if not line or "=" in line.split()[-1] or "=" in line:
                continue  # blank, comment or constant
            kind, field = line.split()[:2]
            annotations[field] = self._field(kind, package)
        namespace = {"__annotations__": annotations, "__module__": __name__}
        pkg, kind, msg = name.split("/")
        made = types.new_class(msg, (IdlStruct,), {"typename": f"{pkg}::{kind}::dds_::{msg}_"},
                               lambda ns: ns.update(namespace))
        return dataclass(made)

    def _field(self, kind: str, package: str) -> Any:
        if kind.endswith("]"):
            inner, _, size = kind[:-1].partition("[")
            element = self._field(inner, package)
            if not size or size.startswith("<="):
                return t.sequence[element]
            return t.array[element, int(size)]
        if kind in PRIMITIVES:
            return PRIMITIVES[kind]
        pkg, _, msg = kind.rpartition("/")
        return self[f"{pkg or package}/msg/{msg}"]

    def build(self, name: str, value: Any) -> Any:
        """A sample of ``name`` from ``value``: a message decoded from a bag (attribute access) or a dict;
        missing fields take their zero."""
        return _build(self[name], value)


def _zero(kind: Any) -> Any:
    if isinstance(kind, type) and is_dataclass(kind):
        return _build(kind, {})
    origin = getattr(kind, "__metadata__", None)
    if origin:
        spec = origin[0]
        if isinstance(spec, t.array):
            return [_zero(spec.subtype)] * spec.length
        if isinstance(spec, t.sequence):
            return []
        return 0.0 if str(spec) in ("float32", "float64") else 0
    return {str: "", bool: False, float: 0.0}.get(kind, 0)


def _build(kind: type, value: Any) -> Any:
    hints = kind.__annotations__
    values = {}
    for f in fields(kind):
        raw = value.get(f.name) if isinstance(value, dict) else getattr(value, f.name, None)
        values[f.name] = _zero(hints[f.name]) if raw is None else _convert(hints[f.name], raw)
    return kind(**values)


def _convert(kind: Any, raw: Any) -> Any:
    if isinstance(kind, type) and is_dataclass(kind):
        return _build(kind, raw)
    spec = getattr(kind, "__metadata__", (None,))[0]
    if isinstance(spec, (t.array, t.sequence)):
        return [_convert(spec.subtype, v) for v in raw]
    return raw


def domain(domain_id: int) -> DomainParticipant:
    """A participant on the loopback interface, in the test's own discovery tag (``$CYCLONEDDS_URI``)."""
    config = ",".join(p for p in (LOOPBACK, os.environ.get("CYCLONEDDS_URI", "")) if p)
    if domain_id not in _DOMAINS:
        _DOMAINS[domain_id] = (Domain(domain_id, config), config)
    if _DOMAINS[domain_id][1] != config:
        raise ValueError(f"domain {domain_id} is set up already, for another discovery tag: take another")
    return DomainParticipant(domain_id)


def unused_domain() -> int:
    """A ROS domain no participant of this process is in (a process keeps each domain's settings)."""
    free = sorted(set(range(100, 200)) - set(_DOMAINS) - _TAKEN)
    chosen = random.SystemRandom().choice(free)
    _TAKEN.add(chosen)
    return chosen


_DOMAINS: dict[int, tuple[Domain, str]] = {}
_TAKEN: set[int] = set()


def isolated(domain_id: int) -> dict[str, str]:
    """The environment of a test's processes: one discovery tag of their own, so that nothing else on the
    machine (another test, another engineer's) takes part."""
    tag = f"lostx-test-{uuid.uuid4().hex}"
    return {**os.environ, "CYCLONEDDS_URI": f"<CycloneDDS><Domain><Discovery><Tag>{tag}</Tag></Discovery>"
                                            f"</Domain></CycloneDDS>", "ROS_DOMAIN_ID": str(domain_id)}


def qos(reliable: bool = True, keep_all: bool = False, transient: bool = False, depth: int = 10) -> Qos:
    return Qos(Policy.Reliability.Reliable(duration(seconds=1)) if reliable else Policy.Reliability.BestEffort,
               Policy.History.KeepAll if keep_all else Policy.History.KeepLast(depth),
               Policy.Durability.TransientLocal if transient else Policy.Durability.Volatile)


class Answers:
    """A subscriber to lostx's answers: every Place and pose, kept in arrival order."""

    def __init__(self, participant: DomainParticipant, kinds: Types, namespace: str = "/lostx") -> None:
        self.place = DataReader(participant, Topic(participant, f"rt{namespace}/place", kinds["lostx_msgs/msg/Place"]),
                                qos(keep_all=True))
        pose_type = kinds["geometry_msgs/msg/PoseWithCovarianceStamped"]
        self.pose = DataReader(participant, Topic(participant, f"rt{namespace}/pose", pose_type), qos(keep_all=True))
        self.places: list[Any] = []
        self.poses: list[Any] = []

    def poll(self) -> None:
        self.places += self.place.take(256)
        self.poses += self.pose.take(256)

    def wait(self, places: int, timeout: float) -> list[Any]:
        end = time.monotonic() + timeout
        while len(self.places) < places and time.monotonic() < end:
            self.poll()
            time.sleep(0.02)
        time.sleep(0.2)
        self.poll()
        return self.places


def wait_matched(entity: Any, timeout: float = 20.0) -> None:
    """Until a writer has a reader (or a reader a writer) on the other side."""
    end = time.monotonic() + timeout
    status = entity.get_publication_matched_status if hasattr(entity, "write") else \
        entity.get_subscription_matched_status
    while status().current_count == 0:
        if time.monotonic() > end:
            raise TimeoutError(f"nothing matched {entity.topic.name} within {timeout:g} s")
        time.sleep(0.02)


def stamp_of(message: Any) -> int:
    return int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)


def publish(bag: Path, domain_id: int, lockstep: str | None, answer_timeout: float) -> int:
    """Replay a bag's messages over DDS in log-time order, as ``ros2 bag play`` does; with ``lockstep`` (the
    answers' namespace), each image waits for its answer before the next goes. Returns the images sent."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    kinds = Types()
    participant = domain(domain_id)
    writers: dict[str, DataWriter] = {}
    with open(bag, "rb") as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        messages = [(channel.topic, schema.name, decoded)
                    for schema, channel, _, decoded in reader.iter_decoded_messages()]
    for topic, schema, _ in messages:
        if topic not in writers:
            transient = topic == "/tf_static"
            writers[topic] = DataWriter(participant, Topic(participant, f"rt{topic}", kinds[schema]),
                                        qos(transient=transient, depth=100))
    answers = Answers(participant, kinds, lockstep) if lockstep else None
    images = [topic for topic, schema, _ in messages if schema.startswith("sensor_msgs/msg/") and "Image" in schema]
    for writer in writers.values():
        wait_matched(writer)
    if answers is not None:
        wait_matched(answers.place)
    # Matched here is not yet matched there: a message written before the other side has found this writer never
    # reaches it (DDS discovery). The test says when it has (lostx logs each publisher it finds).
    print("matched", flush=True)
    if sys.stdin.readline().strip() != "go":
        raise RuntimeError("told to stop before publishing")
    sent = 0
    for topic, schema, decoded in messages:
        writer = writers[topic]
        if topic in images:
            for other in writers.values():  # what came before the frame is there before it
                other.wait_for_acks(duration(seconds=10))
        writer.write(kinds.build(schema, decoded))
        if topic == "/tf_static":
            writer.wait_for_acks(duration(seconds=10))
        if topic in images:
            sent += 1
            if answers is not None:
                answers.wait(sent, answer_timeout)
                if len(answers.places) < sent:
                    raise TimeoutError(f"no answer to image {sent} within {answer_timeout:g} s")
    for writer in writers.values():
        writer.wait_for_acks(duration(seconds=10))
    return sent


def listen(domain_id: int) -> None:
    """Subscribe to the answers (reliable, keep all), say so, and never read them: a subscriber that stalls."""
    participant = domain(domain_id)
    reader = DataReader(participant, Topic(participant, "rt/lostx/place", Types()["lostx_msgs/msg/Place"]),
                        qos(keep_all=True))
    wait_matched(reader, 60)
    print("listening", flush=True)
    while True:
        time.sleep(1)


def main() -> int:
    parser = argparse.ArgumentParser()
    sub = parser.add_subparsers(dest="command", required=True)
    stall = sub.add_parser("listen")
    stall.add_argument("--domain", type=int, required=True)
    play = sub.add_parser("publish")
    play.add_argument("bag", type=Path)
    play.add_argument("--domain", type=int, required=True)
    play.add_argument("--lockstep", metavar="NAMESPACE")
    play.add_argument("--answer-timeout", type=float, default=120.0)
    args = parser.parse_args()
    if args.command == "listen":
        listen(args.domain)
    sent = publish(args.bag, args.domain, args.lockstep, args.answer_timeout)
    print(f"published {sent} images", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

