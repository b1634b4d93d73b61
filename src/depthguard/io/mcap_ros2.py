"""MCAP recordings of ROS 2 messages (profile ``ros2``, schema encoding ``ros2msg``, message encoding
``cdr``): what ``ros2 bag play``, Foxglove, RViz (through a bag) and the ``rosbags`` reader open.

:class:`Ros2McapWriter` writes one ``.mcap`` file; :func:`read_messages` reads any ROS 2 bag (a bare
``.mcap``, or a rosbag2 folder with MCAP or sqlite3 storage) back as ``(topic, typename, t, msg)``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from depthguard.io import ros2
from depthguard.io.ros2_types import stamp_parts

__all__ = ["Ros2McapWriter", "read_messages"]


class Ros2McapWriter:
    """Write ROS 2 messages into an MCAP file.

    Use as a context manager, or call :meth:`close`. Channels are registered on first use of a topic. Each
    message's log and publish time is its ``t`` in nanoseconds, ``round(t * 1e9)`` like the header stamps of
    :func:`depthguard.io.ros2.stamp` (negative ``t`` clamps to 0); messages may come in any order of time
    (readers sort them by log time).

    The summary and the chunk indexes are written by :meth:`close`. A file cut short (the process killed
    while writing) has neither: :func:`read_messages` and ``rosbags`` refuse it, while MCAP's stream reader
    (``mcap.stream_reader.StreamReader``, ``mcap recover``) still reads the messages of its complete chunks
    (up to 1 MiB each).

    Args:
        path: the ``.mcap`` file to create (its folder must exist).
        compression: ``"zstd"`` (default), ``"lz4"`` or ``"none"``.
    """

    def __init__(self, path: str | Path, compression: str = "zstd") -> None:
        from mcap.writer import CompressionType, Writer

        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
        if compression not in comp:
            raise ValueError(f"compression must be one of {sorted(comp)}, got {compression!r}")
        self.path = Path(path)
        self._fh = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        try:
            self._w = Writer(self._fh, compression=comp[compression])
            self._w.start(profile="ros2", library="depthguard")
        except BaseException:
            self._fh.close()
            raise
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self.count = 0

    def _channel(self, topic: str, typename: str) -> int:
        if topic in self._channels:
            cid, known = self._channels[topic]
            if known != typename:
                raise ValueError(f"topic {topic!r} already carries {known}, not {typename}")
            return cid
        if typename not in self._schemas:
            self._schemas[typename] = self._w.register_schema(
                name=typename, encoding="ros2msg", data=ros2.msgdef(typename).encode()
            )
        cid = self._w.register_channel(topic=topic, message_encoding="cdr", schema_id=self._schemas[typename])
        self._channels[topic] = (cid, typename)
        return cid

    def write(self, topic: str, typename: str, msg: Any, t: float) -> None:
        """Add ``msg`` (a ``rosbags`` message of ``typename``) on ``topic`` at log time ``t`` seconds.

        Raises:
            ValueError: the writer is closed; ``t`` is not a finite time below 2**31 s (ROS's Time, 2038);
                ``topic`` already carries another type; ``msg`` does not serialize as ``typename`` (such as
                a header stamp beyond the ``int32`` seconds of ``builtin_interfaces/Time``). The file stays
                as it was before the call.
        """
        if self._fh is None:
            raise ValueError(f"{self.path}: the MCAP writer is closed (message on {topic!r} not written)")
        try:
            sec, nanosec = stamp_parts(t)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(
                f"{self.path}: log time of a message on {topic!r} must be a finite time below 2**31 s (ROS's"
                f" int32 Time.sec), got {t!r}"
            ) from None
        ns = sec * 1_000_000_000 + nanosec
        try:
            data = ros2.serialize(msg, typename)
        except Exception as exc:  # (rosbags raises struct.error, KeyError, AttributeError, ...)
            raise ValueError(
                f"{self.path}: a message on {topic!r} does not serialize as {typename}:"
                f" {type(exc).__name__}: {_one_line(exc)}"
            ) from None
        cid = self._channel(topic, typename)
        self._w.add_message(cid, log_time=ns, publish_time=ns, data=data, sequence=self.count)
        self.count += 1

    def close(self) -> None:
        """Finish the file (summary, index). Safe to call twice."""
        if self._fh is not None:
            fh, self._fh = self._fh, None
            try:
                self._w.finish()
            finally:
                fh.close()

    def __enter__(self) -> Ros2McapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _one_line(exc: BaseException, limit: int = 300) -> str:
    """An exception's text on one line, at most ``limit`` characters (rosbags quotes whole schemas)."""
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _field_names(store, msgtype: str, depth: int = 0) -> list:
    """The field names of ``msgtype`` in ``store``, nested types expanded (a few levels)."""
    out: list = []
    for name, (kind, rest) in store.fielddefs[msgtype][1]:
        sub = rest if getattr(kind, "name", "") == "NAME" else None
        if sub is None and isinstance(rest, tuple) and rest and isinstance(rest[0], tuple):
            if getattr(rest[0][0], "name", "") == "NAME":  # (an array or sequence of messages)
                sub = rest[0][1]
        out.append((name, _field_names(store, sub, depth + 1) if sub in store.fielddefs and depth < 4 else None))
    return out


def _same_definition(path: Path, topic: str, msgtype: str, bag_store, ours) -> None:
    """``ValueError`` naming the bag and the topic when the bag's definition of ``msgtype`` (a type ROS 2 Jazzy
    or DepthGuard defines) has other fields than ours: a damaged or foreign schema would give messages that
    lack fields the pipeline reads (an Image without ``is_bigendian``), failing later far from the cause."""
    if msgtype not in ours.fielddefs or msgtype not in bag_store.fielddefs:
        return
    try:
        same = _field_names(bag_store, msgtype) == _field_names(ours, msgtype)
    except (KeyError, TypeError, ValueError, IndexError):
        same = False
    if not same:
        raise ValueError(
            f"{path}: the bag's definition of {msgtype} on '{topic}' has other fields than ROS 2 Jazzy's"
            " (a damaged or foreign message schema)"
        )


def read_messages(path: str | Path, topics: list[str] | None = None) -> Iterator[tuple[str, str, float, Any]]:
    """``(topic, typename, log time s, message)`` of a ROS 2 bag in log-time order. The log time is the float
    nearest to its nanoseconds / 1e9, so that a message that :class:`Ros2McapWriter` wrote at ``t`` seconds
    of whole nanoseconds reads back at ``t`` exactly (up to 2**51 ns, 26 days; beyond, float64 holds ``t``
    only to its spacing, 0.24 µs at 1.7e9 s since the epoch).

    Args:
        path: a ``.mcap`` file or a rosbag2 folder (``metadata.yaml`` with MCAP or sqlite3 storage).
        topics: only these topics (None = all).
    Raises:
        ValueError: the path is not a readable ROS 2 bag (naming it and the reason); a bag that turns out
            corrupt or truncated while it is read (a chunk that fails its checksum or does not decompress, a
            message that does not deserialize) names the bag, the topic and the message's index on it where
            known, else the index of the message in the bag and the last topic read.
    """
    from rosbags.highlevel import AnyReader

    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such bag (a .mcap file or a rosbag2 folder)")
    try:
        reader = AnyReader([p], default_typestore=ros2.typestore())
        reader.open()
    except Exception as exc:  # rosbags raises several types; name the file in one error
        raise ValueError(f"{p}: not a readable ROS 2 bag ({type(exc).__name__}: {_one_line(exc)})") from None
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        for c in conns:
            _same_definition(p, c.topic, c.msgtype, reader.typestore, ros2.typestore())
        per_topic: dict[str, int] = {}
        n, last = 0, None
        messages = reader.messages(connections=conns)
        while True:
            try:
                item = next(messages, None)
            except Exception as exc:  # (rosbags, zstd, lz4: several types) a corrupt or cut chunk
                after = f" (after message {per_topic[last] - 1} on '{last}')" if last is not None else ""
                raise ValueError(
                    f"{p}: corrupt or truncated bag at message {n}{after}: {type(exc).__name__}: {_one_line(exc)}"
                ) from None
            if item is None:
                break
            conn, t_ns, raw = item
            k = per_topic.get(conn.topic, 0)
            try:
                msg = reader.deserialize(raw, conn.msgtype)
            except Exception as exc:
                raise ValueError(
                    f"{p}: message {k} on '{conn.topic}' ({conn.msgtype}) does not deserialize:"
                    f" {type(exc).__name__}: {_one_line(exc)}"
                ) from None
            per_topic[conn.topic] = k + 1
            n, last = n + 1, conn.topic
            yield conn.topic, conn.msgtype, t_ns / 1e9, msg  # (correctly rounded: ns / 1e9 written reads back)
    finally:
        reader.close()
