"""The background file of a cell (``depthguard commission``; ``[controller] background`` of the cell file).

An ``.npz`` file (``numpy.savez_compressed``, no pickled objects) with:

* ``format`` = ``"depthguard-background"``, ``version`` = 1;
* ``names`` (n,) str: the cameras, in the cell file's order; ``sizes`` (n, 2) int: width, height;
* ``depth_<k>`` (height, width) float32, m, camera k: the nearest valid non-robot depth seen over the frames
  (NaN where no frame gave one);
* the tolerance model per camera: ``noise_coeff`` (n,) (σ = c z², m⁻¹), ``quantization`` (n,) m, ``margin`` (n,) m
  (:func:`depthguard.robot.background.background_threshold`);
* metadata: ``date`` (ISO 8601, UTC), ``frames`` (the frame sets read), ``source``, ``valid_fraction`` (n,):
  the fraction of each camera's pixels with a background depth.

Every reader error is a ``ValueError`` (:class:`~depthguard.errors.InputError`) naming the file.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from depthguard.errors import InputError

__all__ = ["BackgroundFile", "read_background", "write_background", "BACKGROUND_FORMAT"]

BACKGROUND_FORMAT = "depthguard-background"
_VERSION = 1


@dataclass(frozen=True)
class BackgroundFile:
    """A cell's background: per camera its name, the background depth (H, W) float32 m (NaN: none), and the
    tolerance model; plus the metadata of the commissioning."""

    names: tuple[str, ...]
    depths: tuple[np.ndarray, ...]
    noise_coeff: tuple[float, ...]
    quantization: tuple[float, ...]
    margin: tuple[float, ...]
    date: str = ""
    frames: int = 0
    source: str = ""
    valid_fraction: tuple[float, ...] = ()

    def size(self, k: int) -> tuple[int, int]:
        """(width, height) of camera ``k``."""
        h, w = self.depths[k].shape
        return int(w), int(h)

    def thresholds(self) -> list[np.ndarray]:
        """Per camera, the depth at or beyond which a pixel is background
        (:func:`depthguard.robot.background.background_threshold`)."""
        from depthguard.robot.background import background_threshold

        return [
            background_threshold(d, c, q, m)
            for d, c, q, m in zip(self.depths, self.noise_coeff, self.quantization, self.margin, strict=True)
        ]


def write_background(path: str | Path, bg: BackgroundFile) -> Path:
    """Write ``bg`` to ``path`` (``.npz``; the name is kept as given). Returns the path."""
    p = Path(path)
    n = len(bg.names)
    arrays = {
        "format": np.array(BACKGROUND_FORMAT),
        "version": np.array(_VERSION),
        "names": np.array(list(bg.names), dtype=str),
        "sizes": np.array([bg.size(k) for k in range(n)], dtype=np.int64).reshape(n, 2),
        "noise_coeff": np.asarray(bg.noise_coeff, float),
        "quantization": np.asarray(bg.quantization, float),
        "margin": np.asarray(bg.margin, float),
        "date": np.array(bg.date),
        "frames": np.array(int(bg.frames)),
        "source": np.array(bg.source),
        "valid_fraction": np.asarray(bg.valid_fraction, float),
    }
    for k, d in enumerate(bg.depths):
        arrays[f"depth_{k}"] = np.asarray(d, np.float32)
    with open(p, "wb") as f:  # (savez would append ".npz" to a name without it)
        np.savez_compressed(f, **arrays)
    return p


def read_background(path: str | Path) -> BackgroundFile:
    """Read and check a background file; raises :class:`InputError` naming the file and the problem."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such background file")
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise InputError(f"{p}: not a background file (.npz from `depthguard commission`): {exc}") from None
    if str(data.get("format", "")) != BACKGROUND_FORMAT:
        raise InputError(f"{p}: not a background file (no format = {BACKGROUND_FORMAT!r}; `depthguard commission`)")
    if int(data.get("version", -1)) != _VERSION:
        raise InputError(f"{p}: background file version {data.get('version')}, this DepthGuard reads {_VERSION}")
    try:
        names = tuple(str(x) for x in np.atleast_1d(data["names"]))
        n = len(names)
        sizes = np.asarray(data["sizes"], int).reshape(n, 2)
        depths = tuple(np.asarray(data[f"depth_{k}"], np.float32) for k in range(n))
        tol = {
            k: tuple(float(x) for x in np.asarray(data[k], float).reshape(n))
            for k in ("noise_coeff", "quantization", "margin")
        }
        valid = tuple(float(x) for x in np.asarray(data.get("valid_fraction", np.full(n, np.nan)), float).reshape(n))
    except (KeyError, ValueError, TypeError) as exc:
        raise InputError(f"{p}: incomplete background file ({exc})") from None
    for k, (d, (w, h)) in enumerate(zip(depths, sizes, strict=True)):
        if d.shape != (h, w):
            raise InputError(f"{p}: depth_{k} ({names[k]!r}) has shape {d.shape}, sizes says {w}x{h}")
    for key, vals in tol.items():
        if not all(np.isfinite(v) and v >= 0 for v in vals):
            raise InputError(f"{p}: {key} must be finite numbers >= 0, got {list(vals)}")
    return BackgroundFile(
        names=names,
        depths=depths,
        noise_coeff=tol["noise_coeff"],
        quantization=tol["quantization"],
        margin=tol["margin"],
        date=str(data.get("date", "")),
        frames=int(data.get("frames", 0)),
        source=str(data.get("source", "")),
        valid_fraction=valid,
    )
