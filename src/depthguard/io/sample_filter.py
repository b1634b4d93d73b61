"""What a ROS 2 subscription on Zenoh lets through, without any Zenoh (:class:`SampleFilter`): duplicates,
reordered or stale samples, samples stamped in the future, publishers not allowed on the topic and malformed
payloads are dropped and counted by reason. :class:`depthguard.io.zenoh_transport.Subscription` applies it to
every sample.

Why a stamp in the future is dropped: the stamp order is kept per topic, so one sample stamped an hour ahead
(a publisher whose clock jumped, or a bad peer) would otherwise make every later sample "stale" for that hour,
and a controller fed by this topic would hold the arm for the hour. The nodes' clocks must agree far better
than :data:`MAX_FUTURE_S` anyway: the controller refuses data stamped more than one control period ahead of
its own clock (``STOP_INVALID_INPUT``)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from depthguard.io import ros2
from depthguard.io.rmw_zenoh import decode_attachment

__all__ = ["SampleFilter", "MAX_FUTURE_S", "MAX_PUBLISHERS", "MAX_GAPS"]

MAX_FUTURE_S = 0.5
"""How far (s) a header stamp may lie ahead of the receiver's clock and still be taken."""

MAX_PUBLISHERS = 256
"""Publishers (GIDs) whose sequence numbers a filter keeps: a peer that sends every sample under another GID
must not grow it without end. Past this many, the publisher seen first is forgotten: its next sample is
taken as a first one (its stamp must still be newer than the last accepted, so a replay stays dropped)."""

MAX_GAPS = 256
"""Missing sequence numbers kept per publisher, so that a sample that comes late (after later ones) is taken
back out of :attr:`SampleFilter.missed`; a gap of more samples than this is counted and not kept."""


class SampleFilter:
    """What a subscription lets through, without any Zenoh: ``accept(attachment, payload)`` returns the
    decoded ``(message, attachment)`` or None, counting every drop by reason in :attr:`dropped`, and in
    :attr:`missed` the samples that never reached it (gaps in a publisher's sequence numbers: lost on the way
    by a publisher that drops under congestion, or pushed out of a full ``pull`` ring; a sample that arrives
    and is dropped here counts in :attr:`dropped` only, and one that arrives late, after later ones, is taken
    back out of :attr:`missed`, within the last :data:`MAX_GAPS` missing ones of its publisher).

    A message that passes but that the node then refuses (:meth:`reject`) was never applied: the stamp order
    goes back to the last message taken before it, so that one refused message stamped ahead (within
    ``max_future``) does not make the good messages after it "stale".

    Args:
        typename: the ROS type of the payload.
        who: GID (16 bytes) -> publishing node name or None (the graph), used only with ``allowed``.
        allowed: node names that may publish here (None = anyone).
        check_order: drop messages whose header stamp is not newer than the last accepted one, or lies more
            than ``max_future`` seconds after the receiver's clock (``now`` of :meth:`accept`).
        max_future: see ``check_order`` (:data:`MAX_FUTURE_S`).
    """

    def __init__(
        self,
        typename: str,
        who: Callable[[bytes], str | None] | None = None,
        allowed: set[str] | None = None,
        check_order: bool = True,
        max_future: float = MAX_FUTURE_S,
    ) -> None:
        self.typename, self.who, self.allowed, self.check_order = typename, who, allowed, check_order
        self.max_future = float(max_future)
        self.last_seq: dict[bytes, int] = {}
        self.seen_seq: dict[bytes, int] = {}  # per publisher, the highest sequence number that reached here
        self.missed = 0  # samples that never reached here: gaps in a publisher's sequence numbers
        self.last_stamp = -float("inf")
        self._gaps: dict[bytes, set[int]] = {}  # per publisher, the newest missing sequence numbers
        self._undo: float | None = None  # the stamp order before the last accepted message (for reject)
        self.dropped: dict[str, int] = {}
        self.rejected_publishers: set[str] = set()
        self.last_refusal: str | None = None
        self._refusals_said: set[str] = set()

    def _drop(self, why: str) -> None:
        self.dropped[why] = self.dropped.get(why, 0) + 1

    def reject(self, exc: Exception) -> bool:
        """Count a message that passed this filter but that the node could not use (its callback raised
        ``exc``: an image of another encoding, a size that contradicts the data...), by the error's type;
        :attr:`last_refusal` keeps the newest error's text. True the first time this text comes (the
        subscription says it once, not at every message). Called right after :meth:`accept` returned that
        message, it puts the stamp order back to where it was before it (the message was never applied)."""
        if self._undo is not None:
            self.last_stamp, self._undo = self._undo, None
        self._drop(f"refused by the node ({type(exc).__name__})")
        self.last_refusal = str(exc)[:300]
        said = self.last_refusal in self._refusals_said or len(self._refusals_said) >= 20  # (20 kinds at most)
        if not said:
            self._refusals_said.add(self.last_refusal)
        return not said

    def accept(self, attachment: bytes | None, payload: bytes, now: float | None = None) -> tuple[Any, Any] | None:
        """The decoded ``(message, attachment)``, or None when the sample is dropped; ``now``: the receiver's
        clock (s since the epoch; default ``time.time()``)."""
        self._undo = None
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
            self._came_late(att.gid, att.seq)
            self._drop("duplicate or reordered sequence number")
            return None
        seen = self.seen_seq.get(att.gid)
        if seen is None or att.seq > seen:
            if seen is None:
                self._forget_oldest(self.seen_seq)
            elif att.seq > seen + 1:
                self._missing(att.gid, seen, att.seq)  # (lost on the way, or pushed out of a full ring)
            self.seen_seq[att.gid] = att.seq
        elif att.seq < seen:
            self._came_late(att.gid, att.seq)
        try:
            msg = ros2.deserialize(payload, self.typename)
        except Exception:  # noqa: BLE001 - any malformed payload is dropped, never raised into Zenoh
            self._drop("malformed CDR")
            return None
        if self.check_order and hasattr(msg, "header"):
            st = ros2.to_seconds(msg.header.stamp)
            if not st <= (time.time() if now is None else now) + self.max_future:
                self._drop("stamp in the future")
                return None
            if not st > self.last_stamp:
                self._drop("stale or reordered stamp")
                return None
            self._undo, self.last_stamp = self.last_stamp, st
        if att.gid not in self.last_seq:
            self._forget_oldest(self.last_seq)
        self.last_seq[att.gid] = att.seq
        return msg, att

    def _missing(self, gid: bytes, seen: int, seq: int) -> None:
        """Sequence numbers ``seen + 1 .. seq - 1`` of publisher ``gid`` did not come (yet)."""
        self.missed += seq - seen - 1
        gaps = self._gaps.get(gid)
        if gaps is None:
            gaps = self._gaps[gid] = set()
        if seq - seen - 1 >= MAX_GAPS:
            gaps.clear()
            gaps.update(range(seq - MAX_GAPS, seq))
        else:
            gaps.update(range(seen + 1, seq))
            while len(gaps) > MAX_GAPS:
                gaps.discard(min(gaps))

    def _came_late(self, gid: bytes, seq: int) -> None:
        """Sample ``seq`` of ``gid`` came after later ones: no longer missed if it was counted so."""
        gaps = self._gaps.get(gid)
        if gaps and seq in gaps:
            gaps.discard(seq)
            self.missed -= 1

    def _forget_oldest(self, table: dict[bytes, int]) -> None:
        """Make room for one more publisher in ``table`` (at most :data:`MAX_PUBLISHERS`)."""
        while len(table) >= MAX_PUBLISHERS:
            gid = next(iter(table))
            del table[gid]
            if table is self.seen_seq:
                self._gaps.pop(gid, None)
