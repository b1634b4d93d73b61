"""Recording of a simulated run in MCAP (JSON-schema channels, openable in Foxglove).

Channels:

* ``/camera<k>/depth`` (``foxglove.RawImage``): depth images, 16-bit millimetres (``16UC1``, 0 = no
  reading), every third frame (10 Hz); images wider than 320 pixels are subsampled to 320 and recorded
  every sixth frame (5 Hz) to keep the file small;
* ``/camera<k>/calibration`` (``foxglove.CameraCalibration``): intrinsics and pose, once;
* ``/joint_states``: joint positions (rad), 100 Hz;
* ``/control_points``: control sphere centres (m), radii, evaluated distances (m, null = none within ρ);
* ``/repulsion``: the end effector's repulsive velocity (m/s);
* ``/clearance``: evaluated minimum distance and true minimum clearance (m).
"""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np

__all__ = ["record_run"]

_RAW_IMAGE = {
    "title": "foxglove.RawImage",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "width": {"type": "integer"},
        "height": {"type": "integer"},
        "encoding": {"type": "string"},
        "step": {"type": "integer"},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}
_CALIB = {
    "title": "foxglove.CameraCalibration",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object"},
        "frame_id": {"type": "string"},
        "width": {"type": "integer"},
        "height": {"type": "integer"},
        "distortion_model": {"type": "string"},
        "D": {"type": "array", "items": {"type": "number"}},
        "K": {"type": "array", "items": {"type": "number"}},
        "R": {"type": "array", "items": {"type": "number"}},
        "P": {"type": "array", "items": {"type": "number"}},
    },
}


def _plain(title: str, props: dict) -> dict:
    return {"title": title, "type": "object", "properties": props}


def _ts(t: float) -> dict:
    ns = int(round(t * 1e9))
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _num(x):
    x = np.asarray(x, float)
    return [None if not np.isfinite(v) else float(v) for v in x.ravel()]


def record_run(path: str | Path, cell, log, extra=None) -> Path:
    """Write the run's recording to ``path`` (.mcap). Returns the path.

    ``extra(channel, put)``, if given, adds a scenario's own channels: ``channel(topic, schema) -> id`` and
    ``put(id, t, msg)`` (e.g. the octree and the reachability grid of ``saphari-octree``)."""
    from mcap.writer import CompressionType, Writer

    path = Path(path)
    with open(path, "wb") as fh:
        w = Writer(fh, compression=CompressionType.ZSTD)
        w.start(profile="", library="depthguard")

        def channel(topic: str, schema: dict) -> int:
            sid = w.register_schema(name=schema["title"], encoding="jsonschema", data=json.dumps(schema).encode())
            return w.register_channel(topic=topic, message_encoding="json", schema_id=sid)

        def put(ch: int, t: float, msg: dict) -> None:
            ns = int(round(t * 1e9))
            w.add_message(ch, log_time=ns, publish_time=ns, data=json.dumps(msg).encode())

        for k, cam in enumerate(cell.cameras):
            ch = channel(f"/camera{k}/calibration", _CALIB)
            st = max(1, cam.width // 320)  # the recorded images are subsampled by this step (loop._to_mm)
            fx, fy, cx, cy = cam.fx / st, cam.fy / st, cam.cx / st, cam.cy / st
            K = [fx, 0, cx, 0, fy, cy, 0, 0, 1]
            put(
                ch,
                0.0,
                {
                    "timestamp": _ts(0.0),
                    "frame_id": f"camera{k}",
                    "width": -(-cam.width // st),
                    "height": -(-cam.height // st),
                    "distortion_model": "plumb_bob",
                    "D": [0.0] * 5,
                    "K": K,
                    "R": cam.R.ravel().tolist(),
                    "P": [fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0],
                },
            )
        img_ch = [channel(f"/camera{k}/depth", _RAW_IMAGE) for k in range(len(cell.cameras))]
        for t, depths in log.frames:
            for k, d in enumerate(depths):
                put(
                    img_ch[k],
                    t,
                    {
                        "timestamp": _ts(t),
                        "frame_id": f"camera{k}",
                        "width": int(d.shape[1]),
                        "height": int(d.shape[0]),
                        "encoding": "16UC1",
                        "step": int(d.shape[1]) * 2,
                        "data": base64.b64encode(d.tobytes()).decode(),
                    },
                )
        js = channel(
            "/joint_states",
            _plain(
                "depthguard.JointState",
                {"t": {"type": "number"}, "name": {"type": "array"}, "position": {"type": "array"}},
            ),
        )
        cp = channel(
            "/control_points",
            _plain(
                "depthguard.ControlPoints",
                {"names": {"type": "array"}, "centres": {"type": "array"}, "distance": {"type": "array"}},
            ),
        )
        rep = channel("/repulsion", _plain("depthguard.Repulsion", {"v_ee": {"type": "array"}}))
        clr = channel(
            "/clearance",
            _plain(
                "depthguard.Clearance", {"evaluated_min": {"type": ["number", "null"]}, "true_min": {"type": "number"}}
            ),
        )
        names = list(cell.joint_names)
        for i, t in enumerate(log.t):
            put(js, t, {"t": t, "name": names, "position": _num(log.q[i])})
            put(
                cp,
                t,
                {
                    "names": list(log.point_names),
                    "centres": np.asarray(log.centres[i]).round(5).tolist(),
                    "distance": _num(log.eval_points[i]),
                },
            )
            put(rep, t, {"v_ee": _num(log.v_ee[i])})
            put(clr, t, {"evaluated_min": _num([log.eval_min[i]])[0], "true_min": float(log.true_min[i])})
        if extra is not None:
            extra(channel, put)
        w.finish()
    return path
