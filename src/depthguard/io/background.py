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

Every reader error is a ``ValueError`` (:class:`~depthguard.errors.InputError`) naming the file and the field:
a damaged archive, a missing member, another dtype or shape, a depth that is 0, negative or -inf (a
background depth is > 0, or NaN / +inf for none: a negative one would hide every reading behind it), a
tolerance number that is NaN, infinite or negative, duplicate camera names.
"""

from __future__ import annotations

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


def _check_tolerance(where: str, key: str, vals, n: int) -> tuple[float, ...]:
    """``vals`` as n finite floats >= 0, else :class:`InputError` naming ``where`` and ``key``."""
    a = np.asarray(vals)
    if a.dtype.kind not in "fiu" or a.shape != (n,):
        raise InputError(f"{where}: {key} must be {n} number(s), got {a.dtype} of shape {a.shape}")
    x = a.astype(float)
    if not np.all(np.isfinite(x) & (x >= 0)):
        raise InputError(f"{where}: {key} must be finite numbers >= 0, got {x.tolist()}")
    return tuple(float(v) for v in x)


def _check_depth(where: str, key: str, d, name: str) -> np.ndarray:
    """A background depth (H, W) float m: NaN or +inf (no background) or > 0; else :class:`InputError`."""
    a = np.asarray(d)
    if a.dtype.kind != "f" or a.ndim != 2:
        raise InputError(f"{where}: {key} ({name!r}) must be a 2-D float image in metres, got {a.dtype} {a.shape}")
    a = a.astype(np.float32)
    with np.errstate(invalid="ignore"):
        bad = ~np.isnan(a) & ~(a > 0)  # (0, negative, -inf; +inf is no background, as NaN)
    if bad.any():
        v, u = np.argwhere(bad)[0]
        raise InputError(
            f"{where}: {key} ({name!r}) holds {a[v, u]} at pixel (u={u}, v={v}): depths must be > 0 or NaN"
        )
    return a


def write_background(path: str | Path, bg: BackgroundFile) -> Path:
    """Write ``bg`` to ``path`` (``.npz``; the name is kept as given). Returns the path. A ``bg`` that
    :func:`read_background` would refuse (other counts, bad depths or tolerances) raises :class:`InputError`
    before anything is written; an empty ``valid_fraction`` is written as NaN per camera."""
    p = Path(path)
    n = len(bg.names)
    if len(bg.depths) != n or len(set(bg.names)) != n:
        raise InputError(f"{p}: {n} camera name(s) {list(bg.names)} (unique) for {len(bg.depths)} depth image(s)")
    depths = [_check_depth(str(p), f"depth_{k}", d, bg.names[k]) for k, d in enumerate(bg.depths)]
    tol = {k: _check_tolerance(str(p), k, getattr(bg, k), n) for k in ("noise_coeff", "quantization", "margin")}
    valid = np.asarray(bg.valid_fraction, float) if len(bg.valid_fraction) else np.full(n, np.nan)
    if valid.shape != (n,):
        raise InputError(f"{p}: valid_fraction must be {n} number(s), got {valid.shape}")
    arrays = {
        "format": np.array(BACKGROUND_FORMAT),
        "version": np.array(_VERSION),
        "names": np.array(list(bg.names), dtype=str).reshape(n),
        "sizes": np.array([(d.shape[1], d.shape[0]) for d in depths], dtype=np.int64).reshape(n, 2),
        **{k: np.asarray(v, float).reshape(n) for k, v in tol.items()},
        "date": np.array(str(bg.date)),
        "frames": np.array(int(bg.frames)),
        "source": np.array(str(bg.source)),
        "valid_fraction": valid,
    }
    for k, d in enumerate(depths):
        arrays[f"depth_{k}"] = d
    with open(p, "wb") as f:  # (savez would append ".npz" to a name without it)
        np.savez_compressed(f, **arrays)
    return p


def _text(where: str, key: str, a) -> str:
    """A 0-d string member as str, else :class:`InputError`."""
    a = np.asarray(a)
    if a.dtype.kind != "U" or a.ndim != 0:
        raise InputError(f"{where}: {key} must be a text, got {a.dtype} of shape {a.shape}")
    return str(a)


def _integer(where: str, key: str, a, low: int) -> int:
    """A 0-d integer member >= ``low`` as int, else :class:`InputError`."""
    a = np.asarray(a)
    if a.dtype.kind not in "iu" or a.ndim != 0 or int(a) < low:
        raise InputError(f"{where}: {key} must be an integer >= {low}, got {a.dtype} {a.tolist()!r}")
    return int(a)


def read_background(path: str | Path) -> BackgroundFile:
    """Read and check a background file; raises :class:`InputError` naming the file and the field
    (never another exception: a damaged archive is "not a background file")."""
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such background file")
    try:
        with np.load(p, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except Exception as exc:  # (a damaged zip: BadZipFile, zlib.error, NotImplementedError, EOFError, ...)
        raise InputError(f"{p}: not a background file (.npz from `depthguard commission`): {exc!r}") from None
    if not all(isinstance(v, np.ndarray) for v in data.values()):
        raise InputError(f"{p}: not a background file (a member that is not an array)")
    if "format" not in data or str(data["format"]) != BACKGROUND_FORMAT or data["format"].dtype.kind != "U":
        raise InputError(f"{p}: not a background file (no format = {BACKGROUND_FORMAT!r}; `depthguard commission`)")
    if "version" not in data:
        raise InputError(f"{p}: incomplete background file (no version)")
    version = data["version"]
    if version.dtype.kind not in "iu" or version.ndim != 0 or int(version) != _VERSION:
        raise InputError(f"{p}: background file version {version.tolist()!r}, this DepthGuard reads {_VERSION}")
    missing = [k for k in ("names", "sizes", "noise_coeff", "quantization", "margin") if k not in data]
    if missing:
        raise InputError(f"{p}: incomplete background file (no {', '.join(missing)})")
    where = str(p)
    names_a = data["names"]
    if names_a.dtype.kind != "U" or names_a.ndim != 1 or len(names_a) == 0:
        raise InputError(f"{p}: names must be a list of camera names, got {names_a.dtype} of shape {names_a.shape}")
    names = tuple(str(x) for x in names_a)
    n = len(names)
    if len(set(names)) != n or not all(names):
        raise InputError(f"{p}: names must be unique and not empty, got {list(names)}")
    sizes = data["sizes"]
    if sizes.dtype.kind not in "iu" or sizes.shape != (n, 2):
        raise InputError(
            f"{p}: sizes must be {n} integer (width, height) pairs, one per camera of names {list(names)},"
            f" got {sizes.dtype} {sizes.shape}"
        )
    absent = [f"depth_{k}" for k in range(n) if f"depth_{k}" not in data]
    if absent:
        raise InputError(f"{p}: incomplete background file (no {', '.join(absent)} for {n} camera(s))")
    depths = tuple(_check_depth(where, f"depth_{k}", data[f"depth_{k}"], names[k]) for k in range(n))
    for k, (d, (w, h)) in enumerate(zip(depths, sizes.tolist(), strict=True)):
        if d.shape != (h, w):
            raise InputError(f"{p}: depth_{k} ({names[k]!r}) has shape {d.shape}, sizes says {w}x{h}")
    tol = {k: _check_tolerance(where, k, data[k], n) for k in ("noise_coeff", "quantization", "margin")}
    valid = data.get("valid_fraction", np.full(n, np.nan))
    if valid.dtype.kind != "f" or valid.shape != (n,) or np.any(~np.isnan(valid) & ~((valid >= 0) & (valid <= 1))):
        raise InputError(f"{p}: valid_fraction must be {n} fraction(s) in [0, 1] (or NaN), got {valid.tolist()!r}")
    return BackgroundFile(
        names=names,
        depths=depths,
        noise_coeff=tol["noise_coeff"],
        quantization=tol["quantization"],
        margin=tol["margin"],
        date=_text(where, "date", data.get("date", np.array(""))),
        frames=_integer(where, "frames", data.get("frames", np.array(0)), 0),
        source=_text(where, "source", data.get("source", np.array(""))),
        valid_fraction=tuple(float(x) for x in valid),
    )
