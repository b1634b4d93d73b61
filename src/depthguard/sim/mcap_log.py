"""A small MCAP writer for the SAPHARI experiments: JSON messages on JSON-schema channels (Foxglove)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["write_mcap"]


def _clean(x):
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple, np.ndarray)):
        return [_clean(v) for v in (x.tolist() if isinstance(x, np.ndarray) else x)]
    if isinstance(x, (float, np.floating)):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


def write_mcap(path: str | Path, channels: dict[str, list[tuple[float, dict]]]) -> Path:
    """Write ``{topic: [(t_seconds, message_dict), ...]}`` to ``path`` (.mcap, zstd). Non-finite numbers
    become null. Returns the path."""
    from mcap.writer import CompressionType, Writer

    path = Path(path)
    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="depthguard")
        for topic, msgs in channels.items():
            props = {k: {} for k in (msgs[0][1] if msgs else {})}
            schema = {"title": "depthguard" + topic.replace("/", "."), "type": "object", "properties": props}
            sid = w.register_schema(name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode())
            ch = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            for t, msg in msgs:
                ns = int(round(t * 1e9))
                w.add_message(ch, log_time=ns, publish_time=ns, data=json.dumps(_clean(msg)).encode())
        w.finish()
    return path
