"""The ``rmw_zenoh`` wire format (ROS 2 over Zenoh), without ROS and without Zenoh: pure functions.

What an ``rmw_zenoh_cpp`` node puts on the wire, as read in its sources (``liveliness_utils.cpp``,
``attachment_helpers.cpp``, ``qos.cpp``) and its design document:

* **Data key expression** of a topic: ``<domain>/<topic without leading/trailing slash>/<pkg>::msg::dds_::<Type>_/
  RIHS01_<64 hex digits>`` (the ROS 2 type-description hash, REP 2011).
* **Payload**: the CDR bytes of the message with the 4-byte encapsulation header (``00 01 00 00`` =
  CDR little endian), as :func:`depthguard.io.ros2.serialize` writes them.
* **Attachment** of every sample, 33 bytes, Zenoh's serializer format: ``int64`` sequence number (LE),
  ``int64`` source timestamp in ns since the Unix epoch (LE), then the publisher's GID as a sequence: one
  length byte (LEB128 of 16) and 16 bytes.
* **Liveliness tokens** (graph discovery, ``ros2 topic list``): ``@ros2_lv/<domain>/<zid>/<nid>/<id>/<kind>/
  <enclave>/<namespace>/<node>[/<topic>/<type>/<hash>/<qos>]`` with ``kind`` = ``NN`` (node), ``MP``
  (publisher), ``MS`` (subscription), every ``/`` inside a name replaced by ``%``, and the QoS written as
  ``<reliability>:<durability>:<history>,<depth>:<deadline s>,<ns>:<lifespan s>,<ns>:<liveliness>,<s>,<ns>``
  where a field equal to rmw_zenoh's default (reliable, volatile, keep-last 42, infinite durations,
  automatic liveliness) is left empty.

rmw_zenoh derives an entity's GID from the XXH3-128 hash of its liveliness key expression; subscribers treat
the GID as opaque, so DepthGuard derives it from the same string with BLAKE2b-128 (see :func:`entity_gid`).
"""

from __future__ import annotations

import hashlib
import re
import struct
from dataclasses import dataclass
from typing import NamedTuple

__all__ = [
    "ADMIN_SPACE",
    "QoS",
    "QOS_DEFAULT",
    "QOS_SENSOR_DATA",
    "Attachment",
    "dds_type_name",
    "ros_type_name",
    "type_hash",
    "topic_keyexpr",
    "parse_topic_keyexpr",
    "qos_keyexpr",
    "liveliness_token",
    "parse_liveliness_token",
    "entity_gid",
    "encode_attachment",
    "decode_attachment",
    "mangle",
]

ADMIN_SPACE = "@ros2_lv"
_KINDS = ("NN", "MP", "MS", "SS", "SC")


@dataclass(frozen=True)
class QoS:
    """The QoS fields that appear in a liveliness token (``rmw_qos_profile_t`` enum values).

    ``reliability``: 1 reliable, 2 best effort; ``durability``: 1 transient local, 2 volatile; ``history``:
    1 keep last, 2 keep all; ``depth``: queue depth.
    """

    reliability: int = 1
    durability: int = 2
    history: int = 1
    depth: int = 10


#: rclcpp's default publisher QoS (reliable, volatile, keep last 10).
QOS_DEFAULT = QoS()
#: ``rclcpp::SensorDataQoS`` (best effort, keep last 5): what camera drivers publish images with.
QOS_SENSOR_DATA = QoS(reliability=2, depth=5)
#: rmw_zenoh's own defaults (``qos.cpp``): fields equal to these are left empty in a token.
_RMW_ZENOH_DEFAULT = QoS(reliability=1, durability=2, history=1, depth=42)


class Attachment(NamedTuple):
    """A sample's attachment: ``seq`` (int64), ``stamp_ns`` (int64, ns since the Unix epoch), ``gid`` (16 bytes)."""

    seq: int
    stamp_ns: int
    gid: bytes


_NAME_PART = re.compile(r"[A-Za-z][A-Za-z0-9_]*")
_DOMAIN = re.compile(r"[0-9]{1,3}")
_HASH = re.compile(r"RIHS01_[0-9a-f]{64}")


def _split_type(typename: str) -> tuple[str, str, str]:
    parts = str(typename).split("/")
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action") or not all(_NAME_PART.fullmatch(p) for p in parts):
        raise ValueError(f"type name must be 'pkg/msg/Type' (letters, digits, '_'), got {typename!r}")
    return parts[0], parts[1], parts[2]


def dds_type_name(typename: str) -> str:
    """``sensor_msgs/msg/Image`` -> ``sensor_msgs::msg::dds_::Image_`` (the name rmw_zenoh puts on the wire)."""
    pkg, kind, name = _split_type(typename)
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type_name(dds_name: str) -> str:
    """Inverse of :func:`dds_type_name`; raises ``ValueError`` for anything else."""
    parts = str(dds_name).split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_") or len(parts[3]) < 2:
        raise ValueError(f"DDS type name must be 'pkg::msg::dds_::Type_', got {dds_name!r}")
    name = f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"
    try:  # (an empty package, 'pkg::foo::...' or a '/' inside a part is no type name dds_type_name writes)
        _split_type(name)
    except ValueError:
        raise ValueError(f"DDS type name must be 'pkg::msg::dds_::Type_', got {dds_name!r}") from None
    return name


def type_hash(typename: str) -> str:
    """``RIHS01_<64 hex>``: the ROS 2 type-description hash of ``typename`` (rosbags' Jazzy type store)."""
    from depthguard.io.ros2 import typestore

    _split_type(typename)
    return typestore().hash_rihs01(typename)


def _strip_slashes(topic: str) -> str:
    t = str(topic)
    if not t or t.strip("/") == "":
        raise ValueError(f"topic name must be non-empty, like '/camera/depth', got {topic!r}")
    if "//" in t or any(c in t for c in "*$?# "):
        raise ValueError(f"topic name {topic!r} is not a valid ROS 2 topic name")
    return t.strip("/")


def topic_keyexpr(domain: int, topic: str, typename: str, hash_: str | None = None) -> str:
    """The key expression rmw_zenoh publishes ``topic`` of type ``typename`` on in ``domain``."""
    if not isinstance(domain, int) or isinstance(domain, bool) or not 0 <= domain <= 232:
        raise ValueError(f"ROS domain id must be an integer in [0, 232], got {domain!r}")
    h = type_hash(typename) if hash_ is None else hash_
    return f"{domain}/{_strip_slashes(topic)}/{dds_type_name(typename)}/{h}"


class TopicKey(NamedTuple):
    domain: int
    topic: str
    typename: str
    type_hash: str


def parse_topic_keyexpr(key: str) -> TopicKey:
    """Split a data key expression into domain, topic (with its leading slash), ROS type name and hash.

    Raises ``ValueError`` unless the key is ``<domain 0-232>/<topic>/<pkg>::msg::dds_::<Type>_/RIHS01_<64 hex>``."""
    parts = str(key).split("/")
    if (
        len(parts) < 4
        or not _DOMAIN.fullmatch(parts[0])
        or int(parts[0]) > 232
        or not _HASH.fullmatch(parts[-1])
        or not all(parts[1:-2])
    ):
        raise ValueError(f"not an rmw_zenoh topic key expression: {key!r}")
    return TopicKey(int(parts[0]), "/" + "/".join(parts[1:-2]), ros_type_name(parts[-2]), parts[-1])


def mangle(name: str) -> str:
    """rmw_zenoh's ``mangle_name``: every ``/`` becomes ``%``."""
    return str(name).replace("/", "%")


def qos_keyexpr(qos: QoS) -> str:
    """The QoS part of a liveliness token (``qos_to_keyexpr``); durations are always rmw_zenoh's defaults."""
    d = _RMW_ZENOH_DEFAULT

    def f(v: int, dv: int) -> str:
        return "" if v == dv else str(int(v))

    head = f"{f(qos.reliability, d.reliability)}:{f(qos.durability, d.durability)}:"
    return head + f"{f(qos.history, d.history)},{f(qos.depth, d.depth)}:,:,:,,"


def liveliness_token(
    domain: int,
    zid: str,
    nid: int,
    eid: int,
    kind: str,
    node: str,
    *,
    namespace: str = "/",
    enclave: str = "/",
    topic: str | None = None,
    typename: str | None = None,
    qos: QoS = QOS_DEFAULT,
    hash_: str | None = None,
) -> str:
    """The liveliness key expression of a node (``kind="NN"``) or of its publisher / subscription."""
    if kind not in _KINDS:
        raise ValueError(f"entity kind must be one of {_KINDS}, got {kind!r}")
    if not node or "/" in node:
        raise ValueError(f"node name must be non-empty without '/', got {node!r}")
    parts = [ADMIN_SPACE, str(int(domain)), str(zid), str(int(nid)), str(int(eid)), kind]
    parts += [mangle(enclave), mangle(namespace), mangle(node)]
    if kind != "NN":
        if topic is None or typename is None:
            raise ValueError(f"a {kind} token needs topic and typename")
        h = type_hash(typename) if hash_ is None else hash_
        parts += [mangle(topic if topic.startswith("/") else "/" + topic), dds_type_name(typename), h]
        parts.append(qos_keyexpr(qos))
    return "/".join(parts)


class Token(NamedTuple):
    domain: int
    zid: str
    nid: str
    eid: str
    kind: str
    enclave: str
    namespace: str
    node: str
    topic: str | None
    typename: str | None
    type_hash: str | None
    qos: str | None


def parse_liveliness_token(key: str) -> Token:
    """Split a liveliness key expression the way rmw_zenoh's graph cache does (``Entity::make``)."""
    p = str(key).split("/")
    if len(p) < 9 or p[0] != ADMIN_SPACE or p[5] not in _KINDS or not all(p):
        raise ValueError(f"not an rmw_zenoh liveliness token: {key!r}")
    dm = p[6:9]
    un = [s.replace("%", "/") for s in dm]
    if p[5] == "NN":
        return Token(int(p[1]), p[2], p[3], p[4], p[5], *un, None, None, None, None)
    if len(p) != 13:
        raise ValueError(f"a {p[5]} liveliness token has 13 parts, got {len(p)}: {key!r}")
    return Token(int(p[1]), p[2], p[3], p[4], p[5], *un, p[9].replace("%", "/"), ros_type_name(p[10]), p[11], p[12])


def entity_gid(token: str) -> bytes:
    """16-byte GID of an entity, derived from its liveliness token (BLAKE2b-128; rmw_zenoh uses XXH3-128)."""
    return hashlib.blake2b(token.encode(), digest_size=16).digest()


def encode_attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    """The 33-byte attachment: ``<q`` sequence number, ``<q`` timestamp ns, ``0x10`` + 16-byte GID."""
    gid = bytes(gid)
    if len(gid) != 16:
        raise ValueError(f"GID must be 16 bytes, got {len(gid)}")
    return struct.pack("<qqB", int(seq), int(stamp_ns), 16) + gid


def decode_attachment(data: bytes | bytearray | memoryview) -> Attachment:
    """Inverse of :func:`encode_attachment`; ``ValueError`` for anything that is not 33 such bytes."""
    b = bytes(data)
    if len(b) != 33 or b[16] != 16:
        raise ValueError(f"rmw_zenoh attachment must be 33 bytes with a GID of length 16, got {len(b)} bytes")
    seq, stamp = struct.unpack_from("<qq", b, 0)
    return Attachment(seq, stamp, b[17:33])
