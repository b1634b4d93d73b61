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

__all__ = ["Ros2McapWriter", "read_messages"]


class Ros2McapWriter:
    """Write ROS 2 messages into an MCAP file.

    Use as a context manager, or call :meth:`close`. Channels are registered on first use of a topic.

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
        self._w = Writer(self._fh, compression=comp[compression])
        self._w.start(profile="ros2", library="depthguard")
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
        """Add ``msg`` (a ``rosbags`` message of ``typename``) on ``topic`` at log time ``t`` seconds."""
        cid = self._channel(topic, typename)
        ns = int(round(max(t, 0.0) * 1e9))
        self._w.add_message(cid, log_time=ns, publish_time=ns, data=ros2.serialize(msg, typename), sequence=self.count)
        self.count += 1

    def close(self) -> None:
        """Finish the file (summary, index). Safe to call twice."""
        if self._fh is not None:
            self._w.finish()
            self._fh.close()
            self._fh = None

    def __enter__(self) -> Ros2McapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def read_messages(path: str | Path, topics: list[str] | None = None) -> Iterator[tuple[str, str, float, Any]]:
    """``(topic, typename, log time s, message)`` of a ROS 2 bag in log-time order.

    Args:
        path: a ``.mcap`` file or a rosbag2 folder (``metadata.yaml`` with MCAP or sqlite3 storage).
        topics: only these topics (None = all).
    Raises:
        ValueError: the path is not a readable ROS 2 bag (naming it and the reason).
    """
    from rosbags.highlevel import AnyReader

    p = Path(path)
    if not p.exists():
        raise ValueError(f"{p}: no such bag (a .mcap file or a rosbag2 folder)")
    try:
        reader = AnyReader([p], default_typestore=ros2.typestore())
        reader.open()
    except Exception as exc:  # rosbags raises several types; name the file in one error
        raise ValueError(f"{p}: not a readable ROS 2 bag ({type(exc).__name__}: {exc})") from None
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        for conn, t_ns, raw in reader.messages(connections=conns):
            yield conn.topic, conn.msgtype, t_ns * 1e-9, reader.deserialize(raw, conn.msgtype)
    finally:
        reader.close()
