"""``sensor_msgs/msg/JointState`` in CDR without the generic serialiser: the control-rate fast path.

A 1 kHz controller publishes a joint command every cycle, and every node takes the driver's joint states at
its rate. Through ``rosbags``' generic serialiser that costs about 25 µs per command (the message object and
its serialisation) and 19 µs per joint state received, on a core that the distance computation shares.
Here the same bytes take a few microseconds: the encoder writes the stamp and the values into a template
made once per joint list, and the decoder reads the fields where the layout puts them.

Layout (classic CDR, as ROS 2 writes it): a 4-byte encapsulation header (``00 01 00 00`` little-endian,
``00 00 00 00`` big-endian), then, with offsets counted from the end of that header and every primitive
aligned to its own size: ``int32 sec``, ``uint32 nanosec``, ``string frame_id`` (``uint32`` length counting
the NUL, the characters, the NUL), ``string[] name`` (``uint32`` count, each string 4-aligned), then
``float64[] position``, ``velocity`` and ``effort`` (``uint32`` count, then, for a non-empty sequence, the
values 8-aligned).

The decoder accepts only this canonical layout, consumed to the last byte. Anything else comes back as None,
and :func:`depthguard.io.ros2.deserialize` hands it to ``rosbags``, so that the fast path never
decides differently from the reference decoder. The tests compare both ways against ``rosbags``.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from functools import cache
from typing import Any

import numpy as np

from depthguard.io.ros2_types import _t, stamp_parts

__all__ = ["JointStateEncoder", "joint_state_cdr", "decode_joint_state"]

_TYPE = "sensor_msgs/msg/JointState"
_LE_HEADER = b"\x00\x01\x00\x00"


def _pad(n: int, align: int) -> int:
    """Padding that brings offset ``n`` (from the end of the encapsulation header) to a multiple of ``align``."""
    return -n % align


def _string(body: bytearray, text: str) -> None:
    """Append a 4-aligned CDR string (little-endian length counting the NUL) to ``body``."""
    raw = text.encode()
    if b"\x00" in raw:
        raise ValueError(f"JointState string {text!r} holds a NUL character")
    body += bytes(_pad(len(body), 4))
    body += struct.pack("<I", len(raw) + 1) + raw + b"\x00"


class JointStateEncoder:
    """CDR bytes of ``sensor_msgs/msg/JointState`` for a fixed joint list (little-endian, as ROS 2 sends).

    Args:
        names: the joint names, in the order of the values given to :meth:`encode`.
        velocities: whether the messages carry velocities (else the velocity sequence is empty).
        frame_id: the header's frame.

    The effort sequence is empty. The bytes are those of ``rosbags``' serialiser for the same message.
    """

    def __init__(self, names: Sequence[str], velocities: bool = True, frame_id: str = "") -> None:
        self.names = tuple(str(n) for n in names)
        self.velocities = bool(velocities)
        n = len(self.names)
        body = bytearray(8)  # (the stamp, written per message)
        _string(body, frame_id)
        body += bytes(_pad(len(body), 4)) + struct.pack("<I", n)
        for name in self.names:
            _string(body, name)
        offsets = []  # where the positions and the velocities start in the payload
        for count in (n, n if velocities else 0):
            body += bytes(_pad(len(body), 4)) + struct.pack("<I", count)
            if count:
                body += bytes(_pad(len(body), 8))
            offsets.append(len(body) + 4)  # (+ the encapsulation header)
            body += bytes(8 * count)
        body += bytes(_pad(len(body), 4)) + struct.pack("<I", 0)  # effort: empty
        self._template = _LE_HEADER + bytes(body)
        self._offsets = offsets

    def encode(self, t: float, q: np.ndarray, qdot: np.ndarray | None = None) -> bytes:
        """The message stamped ``t`` (s since the epoch) with positions ``q`` (n,) and velocities ``qdot`` (n,)
        (None for an encoder without velocities). Raises ``ValueError`` for another number of values, and for a
        ``t`` that is not finite or whose seconds do not fit the stamp's ``int32`` (2**31 s and later); a
        negative ``t`` clamps to 0, as :func:`~depthguard.io.ros2_types.stamp_parts` says."""
        n = len(self.names)
        q = np.asarray(q, dtype="<f8").reshape(-1)
        if q.shape[0] != n:
            raise ValueError(f"JointState positions: expected {n} values for {n} joints, got {q.shape[0]}")
        try:
            sec, nanosec = stamp_parts(t)
        except (TypeError, ValueError, OverflowError):
            sec = -1
        if not 0 <= sec < 2**31:
            raise ValueError(f"JointState stamp: t must be a finite time below 2**31 s, got {t!r}")
        out = bytearray(self._template)
        struct.pack_into("<iI", out, 4, sec, nanosec)
        o = self._offsets[0]
        out[o : o + 8 * n] = q.tobytes()
        if self.velocities:
            if qdot is None:
                raise ValueError("JointState velocities: this encoder carries velocities, got None")
            v = np.asarray(qdot, dtype="<f8").reshape(-1)
            if v.shape[0] != n:
                raise ValueError(f"JointState velocities: expected {n} values for {n} joints, got {v.shape[0]}")
            o = self._offsets[1]
            out[o : o + 8 * n] = v.tobytes()
        elif qdot is not None:
            raise ValueError("JointState velocities: this encoder carries none, got values")
        return bytes(out)


_ENCODERS: dict[tuple, JointStateEncoder] = {}


def joint_state_cdr(
    t: float, names: Sequence[str], q: np.ndarray, qdot: np.ndarray | None = None, frame_id: str = ""
) -> bytes:
    """CDR bytes of :func:`depthguard.io.ros2.joint_state_msg` ``(t, names, q, qdot, frame_id)``, through an
    encoder kept per joint list."""
    key = (tuple(names), qdot is not None, frame_id)
    enc = _ENCODERS.get(key)
    if enc is None:
        if len(_ENCODERS) >= 64:  # (a node has a few joint lists; never let the cache grow without end)
            _ENCODERS.clear()
        enc = _ENCODERS[key] = JointStateEncoder(names, qdot is not None, frame_id)
    return enc.encode(t, q, qdot)


_U32 = {"<": struct.Struct("<I"), ">": struct.Struct(">I")}
_STAMP = {"<": struct.Struct("<iI"), ">": struct.Struct(">iI")}
_EMPTY = np.zeros(0)
# the names of the last joint state decoded: ``(byte order, offset, the bytes of the names, names, end
# offset)``, replaced as one tuple. A driver sends the same names in every message: comparing their bytes is
# cheaper than reading them again.
_last_names: list = [None]


@cache
def _classes() -> tuple:
    """The ``rosbags`` classes of the message, its header and its stamp."""
    return _t(_TYPE), _t("std_msgs/msg/Header"), _t("builtin_interfaces/msg/Time")


def _count(data: bytes, pos: int, u32: struct.Struct) -> tuple[int, int]:
    """``(value, offset after it)`` of the 4-aligned ``uint32`` at or after ``pos`` (offsets in the payload)."""
    pos += -(pos - 4) % 4
    if pos + 4 > len(data):
        raise ValueError("truncated")
    return u32.unpack_from(data, pos)[0], pos + 4


def _string_at(data: bytes, pos: int, u32: struct.Struct) -> tuple[str, int]:
    """``(text, offset after it)`` of the CDR string at or after ``pos``."""
    n, pos = _count(data, pos, u32)
    end = pos + n
    if n < 1 or end > len(data) or data[end - 1] != 0:
        raise ValueError("bad string")
    return data[pos : end - 1].decode(), end


def _names_at(data: bytes, pos: int, order: str) -> tuple[list[str], int]:
    """``(names, offset after them)`` of the string sequence at ``pos``, from :data:`_last_names` when its
    bytes are those of the last message's."""
    last = _last_names[0]
    if last is not None and last[0] == order and last[1] == pos and data.startswith(last[2], pos):
        return list(last[3]), last[4]
    u32 = _U32[order]
    n, p = _count(data, pos, u32)
    names = []
    for _ in range(n):
        name, p = _string_at(data, p, u32)
        names.append(name)
    _last_names[0] = (order, pos, data[pos:p], tuple(names), p)
    return names, p


def _floats_at(data: bytes, pos: int, order: str) -> tuple[np.ndarray, int]:
    """``(values, offset after them)`` of the ``float64`` sequence at ``pos`` (a native, writable copy)."""
    n, pos = _count(data, pos, _U32[order])
    if n == 0:
        return _EMPTY.copy(), pos
    pos += -(pos - 4) % 8
    end = pos + 8 * n
    if end > len(data):
        raise ValueError("truncated")
    return np.frombuffer(data, dtype=order + "f8", count=n, offset=pos).astype(np.float64), end


def decode_joint_state(data: bytes | bytearray | memoryview) -> Any | None:
    """The ``sensor_msgs/msg/JointState`` (a ``rosbags`` message object) of CDR bytes in the canonical layout,
    or None for anything else (another encapsulation, a truncated or longer payload, a bad string): the
    caller then asks the generic decoder, which decodes or refuses it."""
    if not isinstance(data, bytes):
        data = bytes(data)
    if len(data) < 12 or data[0] != 0 or data[1] > 1 or data[2] != 0 or data[3] != 0:
        return None
    order = "<" if data[1] == 1 else ">"
    try:
        sec, nanosec = _STAMP[order].unpack_from(data, 4)
        frame_id, pos = _string_at(data, 12, _U32[order])
        names, pos = _names_at(data, pos, order)
        position, pos = _floats_at(data, pos, order)
        velocity, pos = _floats_at(data, pos, order)
        effort, pos = _floats_at(data, pos, order)
    except (ValueError, UnicodeDecodeError):
        return None
    if pos != len(data):
        return None
    msg_t, header_t, time_t = _classes()
    header = header_t(stamp=time_t(sec=sec, nanosec=nanosec), frame_id=frame_id)
    return msg_t(header=header, name=names, position=position, velocity=velocity, effort=effort)
