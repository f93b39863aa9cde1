"""The DDS side of ``lostx ros2``: the Cyclone DDS domain (which network, which ROS domain) and the QoS of each
topic, as ROS 2's ``rmw_cyclonedds`` sets them up.

``loopback`` (the default) keeps every packet on this machine and finds the ROS 2 nodes on it however they
discover: by multicast on the loopback interface (``ROS_LOCALHOST_ONLY=1`` in Humble) and by unicast to the
participant ports of localhost (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` in Jazzy and later, whose
settings it copies: participant indices up to 32, ``localhost`` as a peer). An interface's name or address
puts lostx on that network with Cyclone DDS's defaults there (multicast discovery); ``auto`` lets Cyclone DDS
choose. ``$CYCLONEDDS_URI`` is read after lostx's own settings and overrides them, as ROS 2 nodes read it.
"""

from __future__ import annotations

import ipaddress
import os
from typing import Any
from xml.sax.saxutils import quoteattr

from lostx.core.config import Ros2Config
from lostx.core.errors import InputError

LOOPBACK = "loopback"
AUTO = "auto"
MAX_AUTO_PARTICIPANT_INDEX = 32
"""As ROS 2's localhost discovery range sets it: the ROS 2 processes on one machine that find each other."""
MAX_BLOCKING_S = 0.1
"""Longest a reliable writer may wait for room (only a keep-all history ever waits; lostx's writers keep last)."""
TF_STATIC_DEPTH = 100
"""tf2's static listener keeps this many (transient local: a late joiner gets every static transform)."""
SIDE_DEPTH = 100
"""Camera infos and odometry messages held between two looks (a look comes with every frame)."""
KEEP_ALL_FRAMES = 16
"""Keep-all images: frames held waiting for the localizer before a reliable publisher is made to wait."""


def cyclone_config(interface: str) -> str:
    """The Cyclone DDS configuration (XML) for ``interface``; ``$CYCLONEDDS_URI`` follows it, overriding it."""
    own = _interface_config(interface)
    user = os.environ.get("CYCLONEDDS_URI", "").strip()
    return ",".join(part for part in (own, user) if part)


def _interface_config(interface: str) -> str:
    if interface == AUTO:
        return ""
    if interface == LOOPBACK:
        return ('<CycloneDDS><Domain id="any"><General><Interfaces>'
                '<NetworkInterface address="127.0.0.1" multicast="true"/></Interfaces></General>'
                f'<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>'
                f'{MAX_AUTO_PARTICIPANT_INDEX}</MaxAutoParticipantIndex><Peers><Peer address="localhost"/></Peers>'
                '</Discovery></Domain></CycloneDDS>')
    if not interface or any(c in interface for c in "<>&\"'"):
        raise InputError(f"--interface {interface!r}: give a network interface's name (eth0) or address, "
                         f"{LOOPBACK} or {AUTO}")
    try:
        ipaddress.ip_address(interface)
        attribute = "address"
    except ValueError:
        attribute = "name"
    return (f'<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface {attribute}={quoteattr(interface)}/>'
            f'</Interfaces></General></Domain></CycloneDDS>')


def domain_id(config: Ros2Config) -> int:
    """The ROS domain: the setting, else ``$ROS_DOMAIN_ID``, else 0."""
    if config.domain_id is not None:
        return config.domain_id
    text = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not text:
        return 0
    if not text.isdigit() or int(text) > 232:
        raise InputError(f"ROS_DOMAIN_ID={text!r} is not a ROS domain (0 to 232); unset it or give --domain-id")
    return int(text)


def participant(config: Ros2Config) -> Any:
    """A DDS participant in the configured ROS domain, on the configured network."""
    from cyclonedds.core import DDSException
    from cyclonedds.domain import Domain, DomainParticipant

    did = domain_id(config)
    try:
        domain = Domain(did, cyclone_config(config.interface))
        member = DomainParticipant(did)
    except DDSException as exc:
        raise InputError(f"cannot join ROS domain {did} on interface {config.interface!r} ({exc}); check the "
                         f"interface's name or address (ip address), and $CYCLONEDDS_URI if set") from None
    member._lostx_domain = domain  # the domain's configuration lives as long as the participant
    return member


def _reliability(kind: str) -> Any:
    from cyclonedds.core import Policy
    from cyclonedds.util import duration

    if kind == "reliable":
        return Policy.Reliability.Reliable(duration(seconds=MAX_BLOCKING_S))
    return Policy.Reliability.BestEffort


def _read_representations() -> Any:
    """Readers take plain CDR (XCDR1, what ROS 2 sends) and XCDR2 alike: Cyclone DDS decodes either."""
    from cyclonedds.core import Policy

    return Policy.DataRepresentation(use_cdrv0_representation=True, use_xcdrv2_representation=True)


def image_qos(config: Ros2Config) -> Any:
    """Images and camera infos: ROS's sensor-data profile (best effort, keep last 5) unless set otherwise."""
    from cyclonedds.core import Policy, Qos

    keep_all = config.image_reliability == "reliable" and config.image_depth == 0
    if keep_all:  # every frame, and no more than KEEP_ALL_FRAMES waiting: then the publisher is held back
        limits = Policy.ResourceLimits(max_samples=KEEP_ALL_FRAMES, max_instances=1,
                                       max_samples_per_instance=KEEP_ALL_FRAMES)
        return Qos(_reliability("reliable"), Policy.History.KeepAll, limits, Policy.Durability.Volatile,
                   _read_representations())
    return Qos(_reliability(config.image_reliability), Policy.History.KeepLast(max(config.image_depth, 1)),
               Policy.Durability.Volatile, _read_representations())


def side_qos(reliability: str) -> Any:
    """Odometry and camera infos: kept until the next frame takes them."""
    from cyclonedds.core import Policy, Qos

    return Qos(_reliability(reliability), Policy.History.KeepLast(SIDE_DEPTH), Policy.Durability.Volatile,
               _read_representations())


def tf_static_qos() -> Any:
    """``/tf_static`` as tf2 publishes it: reliable and transient local, so the transforms published before
    lostx started still reach it."""
    from cyclonedds.core import Policy, Qos

    return Qos(_reliability("reliable"), Policy.History.KeepLast(TF_STATIC_DEPTH), Policy.Durability.TransientLocal,
               _read_representations())


def answer_qos(config: Ros2Config) -> Any:
    """The answers: reliable, keep last (a stalled subscriber loses the oldest answers and never holds up the
    localizer; keep all would make every write wait for it), in plain CDR (XCDR1) alone, as ``rmw_cyclonedds``
    writes ROS 2 messages."""
    from cyclonedds.core import Policy, Qos

    durability = (Policy.Durability.TransientLocal if config.answer_durability == "transient_local"
                  else Policy.Durability.Volatile)
    return Qos(_reliability(config.answer_reliability), Policy.History.KeepLast(config.answer_depth), durability,
               Policy.DataRepresentation(use_cdrv0_representation=True))
