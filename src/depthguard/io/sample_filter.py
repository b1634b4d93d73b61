"""What a ROS 2 subscription on Zenoh lets through, without any Zenoh (:class:`SampleFilter`): duplicates,
reordered or stale samples, publishers not allowed on the topic and malformed payloads are dropped and counted
by reason. :class:`depthguard.io.zenoh_transport.Subscription` applies it to every sample."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from depthguard.io import ros2
from depthguard.io.rmw_zenoh import decode_attachment

__all__ = ["SampleFilter"]


class SampleFilter:
    """What a subscription lets through, without any Zenoh: ``accept(attachment, payload)`` returns the
    decoded ``(message, attachment)`` or None, counting every drop by reason in :attr:`dropped`.

    Args:
        typename: the ROS type of the payload.
        who: GID (16 bytes) -> publishing node name or None (the graph), used only with ``allowed``.
        allowed: node names that may publish here (None = anyone).
        check_order: drop messages whose header stamp is not newer than the last accepted one.
    """

    def __init__(
        self,
        typename: str,
        who: Callable[[bytes], str | None] | None = None,
        allowed: set[str] | None = None,
        check_order: bool = True,
    ) -> None:
        self.typename, self.who, self.allowed, self.check_order = typename, who, allowed, check_order
        self.last_seq: dict[bytes, int] = {}
        self.last_stamp = -float("inf")
        self.dropped: dict[str, int] = {}
        self.rejected_publishers: set[str] = set()

    def _drop(self, why: str) -> None:
        self.dropped[why] = self.dropped.get(why, 0) + 1

    def accept(self, attachment: bytes | None, payload: bytes) -> tuple[Any, Any] | None:
        try:
            att = decode_attachment(attachment if attachment is not None else b"")
        except ValueError:
            self._drop("bad attachment")
            return None
        if self.allowed is not None:
            name = self.who(att.gid) if self.who is not None else None
            if name not in self.allowed:
                self._drop("publisher not allowed")
                self.rejected_publishers.add(str(name))
                return None
        if att.seq <= self.last_seq.get(att.gid, -(2**63) - 1):
            self._drop("duplicate or reordered sequence number")
            return None
        try:
            msg = ros2.deserialize(payload, self.typename)
        except Exception:  # noqa: BLE001 - any malformed payload is dropped, never raised into Zenoh
            self._drop("malformed CDR")
            return None
        if self.check_order and hasattr(msg, "header"):
            st = ros2.to_seconds(msg.header.stamp)
            if not st > self.last_stamp:
                self._drop("stale or reordered stamp")
                return None
            self.last_stamp = st
        self.last_seq[att.gid] = att.seq
        return msg, att
