"""ROS 2 publishers and subscribers on Zenoh in the ``rmw_zenoh`` format (:mod:`depthguard.io.rmw_zenoh`).

A :class:`ZenohNode` is one Zenoh session in peer mode with the liveliness token of a ROS 2 node; its
publishers declare ``MP`` tokens and put CDR payloads with the 33-byte attachment; its subscriptions declare
``MS`` tokens, decode the payload with the Jazzy type store and drop what must not reach a safety stage:

* **duplicates** (a sequence number already seen from the same publisher GID),
* **reordered or stale samples** (a header stamp not newer than the last accepted one on that topic),
* samples from publishers that are **not allowed** on the topic (see ``allowed`` in :meth:`subscribe`):
  the publisher is identified by the GID of its attachment, matched to the liveliness tokens of the graph.

Every drop is counted in :attr:`Subscription.dropped` with its reason.

Network defaults (:func:`session_config`): peer mode, multicast scouting off, listening only on the
loopback endpoints given, connecting to the ROS 2 Zenoh router at ``tcp/127.0.0.1:7447`` (never listening
there) and to the other DepthGuard nodes; Zenoh keeps retrying endpoints that do not answer, so a node starts
and runs when nothing listens.
"""

from __future__ import annotations

import json
import sys
import threading
import time
import weakref
from collections.abc import Callable
from typing import Any

from depthguard.io import ros2
from depthguard.io.rmw_zenoh import (
    QOS_DEFAULT,
    QoS,
    encode_attachment,
    entity_gid,
    liveliness_token,
    parse_liveliness_token,
    topic_keyexpr,
)
from depthguard.io.sample_filter import SampleFilter

__all__ = [
    "ROUTER_ENDPOINT",
    "session_config",
    "acl_put_keys",
    "close_open_nodes",
    "ZenohNode",
    "RosPublisher",
    "Subscription",
    "SampleFilter",
]

#: Where the ROS 2 Zenoh router (``ros2 run rmw_zenoh_cpp rmw_zenohd``) listens.
ROUTER_ENDPOINT = "tcp/127.0.0.1:7447"


def _zenoh():
    try:
        import zenoh
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError(f"Zenoh transport needs the 'net' extra: pip install 'depthguard[net]' ({exc})") from None
    return zenoh


def session_config(
    listen: list[str],
    connect: list[str],
    tls: dict[str, str] | None = None,
    access_control: dict[str, Any] | None = None,
):
    """A ``zenoh.Config``: peer mode, no multicast scouting, the given endpoints, background retries.

    ``tls``: ``{"root_ca_certificate": path, "listen_certificate": path, "listen_private_key": path}`` for
    ``tls/`` endpoints (Zenoh's TLS transport); endpoints on other hosts should use it. ``access_control``:
    Zenoh's ACL section (:func:`depthguard.io.zenoh_acl.access_control`).
    """
    zenoh = _zenoh()
    for e in list(listen) + list(connect):
        if not isinstance(e, str) or "/" not in e:
            raise ValueError(f"Zenoh endpoint must look like 'tcp/127.0.0.1:7447', got {e!r}")
    if ROUTER_ENDPOINT in listen:
        raise ValueError(f"{ROUTER_ENDPOINT} is the ROS 2 router's port: DepthGuard never listens on it")
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps(list(listen)))
    c.insert_json5("connect/endpoints", json.dumps(list(connect)))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/exit_on_failure", json.dumps({"router": False, "peer": False, "client": False}))
    c.insert_json5("connect/retry", "{period_init_ms: 100, period_max_ms: 1000, period_increase_factor: 1.5}")
    c.insert_json5("listen/exit_on_failure", json.dumps({"router": True, "peer": True, "client": True}))
    if tls:
        c.insert_json5("transport/link/tls", json.dumps(tls))
    if access_control:
        c.insert_json5("access_control", json.dumps(access_control))
    return c


def acl_put_keys(access_control: dict[str, Any]) -> set[str]:
    """The key expressions on which some rule of Zenoh's ACL section allows a ``put``."""
    return {k for r in access_control.get("rules", []) if "put" in r.get("messages", []) for k in r["key_exprs"]}


class RosPublisher:
    """One ROS 2 publisher: CDR payload + attachment (sequence number, time stamp, GID)."""

    def __init__(self, node: ZenohNode, topic: str, typename: str, qos: QoS, eid: int) -> None:
        self.topic, self.typename = topic, typename
        self.key = topic_keyexpr(node.domain, topic, typename)
        self.token = liveliness_token(
            node.domain, node.zid, node.nid, eid, "MP", node.name, topic=topic, typename=typename, qos=qos
        )
        self.gid = entity_gid(self.token)
        self._lv = node.session.liveliness().declare_token(self.token)
        zenoh = _zenoh()
        rel = zenoh.Reliability.BEST_EFFORT if qos.reliability == 2 else zenoh.Reliability.RELIABLE
        self._pub = node.session.declare_publisher(
            self.key, reliability=rel, congestion_control=zenoh.CongestionControl.DROP
        )
        self.seq = 0

    def publish(self, msg: Any, stamp_ns: int | None = None) -> int:
        """Serialise ``msg`` and put it; returns the attachment's time stamp (ns since the epoch)."""
        return self.put_cdr(ros2.serialize(msg, self.typename), stamp_ns)

    def put_cdr(self, payload: bytes, stamp_ns: int | None = None, seq: int | None = None) -> int:
        """Put ready CDR bytes (``seq``: override the sequence number, for fault tests)."""
        self.seq += 1
        ts = time.time_ns() if stamp_ns is None else int(stamp_ns)
        self._pub.put(payload, attachment=encode_attachment(self.seq if seq is None else seq, ts, self.gid))
        return ts

    def close(self) -> None:
        self._pub.undeclare()
        self._lv.undeclare()


def _in_shared_memory(payload) -> bool:
    """Whether a sample's payload lies in Zenoh's shared memory (its ``as_shm`` is an unstable API: False
    where it is missing)."""
    try:
        return payload.as_shm() is not None
    except Exception:  # noqa: BLE001 - a Zenoh build without shared memory
        return False


class Subscription:
    """One ROS 2 subscription; ``callback(msg, attachment, receive_ns)`` runs on Zenoh's thread for every
    sample that :class:`SampleFilter` lets through.

    With ``pull`` > 0 the samples wait instead in a ring of that many (the oldest dropped when it is full),
    without waking a Python thread, until :meth:`drain` runs the callback on them in the caller's thread;
    ``receive_ns`` is then the time of the drain. For a topic at a high rate that a node needs only now
    and then (the distance node's joint states at the driver's rate, read once per frame set).
    """

    def __init__(
        self,
        node: ZenohNode,
        topic: str,
        typename: str,
        callback: Callable[[Any, Any, int], None],
        eid: int,
        allowed: set[str] | None,
        check_order: bool,
        pull: int = 0,
    ) -> None:
        self.node, self.topic, self.typename, self.callback = node, topic, typename, callback
        self.key = topic_keyexpr(node.domain, topic, typename)
        tok = liveliness_token(node.domain, node.zid, node.nid, eid, "MS", node.name, topic=topic, typename=typename)
        self._lv = node.session.liveliness().declare_token(tok)
        self.filter = SampleFilter(typename, node.publisher_node, allowed, check_order)
        self.received = 0
        self.shm_received = 0  # of them, how many came through Zenoh's shared memory
        self.pull = int(pull)
        handler = _zenoh().handlers.RingChannel(self.pull) if self.pull > 0 else self._on_sample
        self._sub = node.session.declare_subscriber(self.key, handler)

    @property
    def dropped(self) -> dict[str, int]:
        return self.filter.dropped

    @property
    def missed(self) -> int:
        """Samples that never reached the filter (:attr:`SampleFilter.missed`): lost on the way, or pushed out
        of a full ``pull`` ring."""
        return self.filter.missed

    @property
    def rejected_publishers(self) -> set[str]:
        """Node names of the publishers whose samples were dropped as not allowed."""
        return self.filter.rejected_publishers

    @property
    def unlisted_publishers(self) -> set[str]:
        """Publishers declared on this topic that are not allowed (:meth:`ZenohNode.unlisted_publishers`);
        empty when anyone may publish here. With Zenoh's access control their samples never arrive, so
        this is where they are reported."""
        if self.filter.allowed is None:
            return set()
        return self.node.unlisted_publishers(self.topic, self.filter.allowed)

    def _on_sample(self, sample) -> None:
        now = time.time_ns()
        att = sample.attachment.to_bytes() if sample.attachment is not None else None
        got = self.filter.accept(att, sample.payload.to_bytes(), now * 1e-9)
        if got is None:
            return
        self.received += 1
        if _in_shared_memory(sample.payload):
            self.shm_received += 1
        try:
            self.callback(got[0], got[1], now)
        except Exception as exc:  # noqa: BLE001 - a message the node cannot use: counted, never raised into Zenoh
            if self.filter.reject(exc):  # (one line per kind of refusal, not one per message)
                print(f"depthguard {self.node.name}: refused a message on {self.topic}: {exc}", file=sys.stderr)

    def drain(self) -> int:
        """Run the callback on every sample waiting in a ``pull`` subscription's ring, oldest first, in this
        thread; returns how many there were (0 at once for a subscription that is not ``pull``)."""
        if self.pull <= 0:
            return 0
        n = 0
        while (sample := self._sub.try_recv()) is not None:
            self._on_sample(sample)
            n += 1
        return n

    def close(self) -> None:
        self._sub.undeclare()
        self._lv.undeclare()


_OPEN_NODES: weakref.WeakSet = weakref.WeakSet()


def close_open_nodes() -> int:
    """Close every :class:`ZenohNode` of this process that is still open; returns how many. A node whose
    set-up raises after its session opened calls this: an open session keeps Zenoh's threads, and with them
    the process, alive after the error."""
    nodes = list(_OPEN_NODES)
    for n in nodes:
        n.close()
    return len(nodes)


class ZenohNode:
    """A ROS 2 node on Zenoh: one session, its ``NN`` liveliness token, publishers and subscriptions.

    Args:
        name: node name (no ``/``).
        domain: ROS domain id.
        listen: endpoints to listen on (loopback by default); ``connect``: endpoints to connect to
            (default: the ROS 2 router at ``tcp/127.0.0.1:7447``).
        tls: Zenoh's TLS link settings (:func:`session_config`).
        access_control: Zenoh's ACL section; with it, the peers' certificate common names identify them in
            :meth:`unlisted_publishers` too (one certificate per node).
    """

    def __init__(
        self,
        name: str,
        *,
        domain: int = 0,
        listen: list[str] | None = None,
        connect: list[str] | None = None,
        tls: dict[str, str] | None = None,
        access_control: dict[str, Any] | None = None,
    ) -> None:
        zenoh = _zenoh()
        self.name, self.domain = str(name), int(domain)
        conf = session_config(listen or [], [ROUTER_ENDPOINT] if connect is None else connect, tls, access_control)
        self.session = zenoh.open(conf)
        self.entities: list[Any] = []
        self._closed = False
        _OPEN_NODES.add(self)  # (from here on, close_open_nodes() can close it, whatever fails below)
        self.identified = bool(access_control)
        self._acl_keys = None if not access_control else acl_put_keys(access_control)
        self.zid = str(self.session.info.zid())
        self.nid = 0
        self._eid = 0
        self.token = liveliness_token(self.domain, self.zid, self.nid, self._next_eid(), "NN", self.name)
        self._lv = self.session.liveliness().declare_token(self.token)
        self._graph: dict[bytes, Any] = {}  # GID -> the publisher's liveliness token (parsed)
        self._glock = threading.Lock()
        self._graph_sub = self.session.liveliness().declare_subscriber(
            f"@ros2_lv/{self.domain}/**", self._on_token, history=True
        )

    def __enter__(self) -> ZenohNode:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _next_eid(self) -> int:
        e = self._eid
        self._eid += 1
        return e

    def _on_token(self, sample) -> None:
        key = str(sample.key_expr)
        try:
            tok = parse_liveliness_token(key)
        except ValueError:
            return
        if tok.kind != "MP":
            return
        with self._glock:
            if sample.kind == _zenoh().SampleKind.DELETE:
                self._graph.pop(entity_gid(key), None)
            else:
                self._graph[entity_gid(key)] = tok

    def publisher_node(self, gid: bytes) -> str | None:
        """Name of the node whose publisher has ``gid`` (from the graph's liveliness tokens), None if unknown."""
        with self._glock:
            tok = self._graph.get(bytes(gid))
        return None if tok is None else tok.node

    def peer_identities(self) -> dict[str, str]:
        """Zenoh id of each directly linked peer -> the common name of its TLS certificate (peers whose
        link carries none are left out)."""
        out = {}
        try:
            links = list(self.session.info.links())
        except Exception:  # noqa: BLE001 - a closed or half-dead session: no identities
            return out
        for link in links:
            ident = getattr(link, "auth_identifier", None)
            if ident:
                out[str(link.zid)] = str(ident)
        return out

    def unlisted_publishers(self, topic: str, allowed: set[str]) -> set[str]:
        """The publishers declared on ``topic`` in the ROS graph that are not ``allowed``: their node name,
        and, with access control (:attr:`identified`), ``"name (certificate CN)"`` for a publisher whose
        certificate's common name is not its node name or not allowed (a peer that took a listed name)."""
        with self._glock:
            toks = [t for t in self._graph.values() if t.topic == topic and t.zid != self.zid]
        ids = self.peer_identities() if self.identified and toks else {}
        out = set()
        for t in toks:
            cn = ids.get(t.zid)
            if t.node not in allowed:
                out.add(t.node if cn in (None, t.node) else f"{t.node} (certificate {cn})")
            elif self.identified and cn != t.node:
                out.add(f"{t.node} (certificate {cn or 'unknown'})")
        return out

    def _check_acl(self, topic: str, typename: str) -> None:
        if self._acl_keys is not None and topic_keyexpr(self.domain, topic, typename) not in self._acl_keys:
            raise ValueError(
                f"topic {topic} of type {typename} is not in this node's access control (Zenoh would drop"
                " its samples): add it to the cell's topics (nodes.common.Topics.typed)"
            )

    def publisher(self, topic: str, typename: str, qos: QoS = QOS_DEFAULT) -> RosPublisher:
        self._check_acl(topic, typename)
        p = RosPublisher(self, topic, typename, qos, self._next_eid())
        self.entities.append(p)
        return p

    def subscribe(
        self,
        topic: str,
        typename: str,
        callback: Callable[[Any, Any, int], None],
        *,
        allowed: set[str] | None = None,
        check_order: bool = True,
        pull: int = 0,
    ) -> Subscription:
        """Subscribe; ``allowed``: node names that may publish on this topic (None = anyone); ``pull``: keep
        up to that many samples for :meth:`Subscription.drain` instead of a callback per sample."""
        self._check_acl(topic, typename)
        s = Subscription(self, topic, typename, callback, self._next_eid(), allowed, check_order, pull)
        self.entities.append(s)
        return s

    def close(self) -> None:
        """Undeclare everything and close the session (once; later calls do nothing)."""
        if self._closed:
            return
        self._closed = True
        _OPEN_NODES.discard(self)
        for e in self.entities:
            try:
                e.close()
            except Exception:  # noqa: BLE001 - closing a half-dead session must not raise
                pass
        try:
            self._lv.undeclare()
            self._graph_sub.undeclare()
        except Exception:  # noqa: BLE001
            pass
        self.session.close()
