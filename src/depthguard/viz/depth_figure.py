"""A picture of one depth image with the control points and their repulsive vectors."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from depthguard.camera import Camera

__all__ = ["save_depth_figure"]


def save_depth_figure(
    path: str | Path,
    camera: Camera,
    depth: np.ndarray,
    centres: np.ndarray,
    names: list[str],
    repulsive: np.ndarray,
    distances: np.ndarray,
    mask: np.ndarray | None = None,
    arrow_scale: float = 0.25,
    title: str = "",
) -> Path:
    """Draw the depth image, each control point (coloured by distance) and its repulsive vector.

    Args:
        path: output PNG.
        camera, depth: the camera and its (H, W) depth image (metres, NaN = no reading).
        centres: (N, 3) control points (world); names: their labels.
        repulsive: (N, 3) repulsive vectors (world, m/s), drawn as arrows of ``arrow_scale`` s length.
        distances: (N,) distances (m, inf = none).
        mask: optional robot mask, drawn in white.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 6.4), dpi=110)
    shown = np.where(np.isfinite(depth), depth, np.nan)
    im = ax.imshow(
        shown, cmap="viridis_r", vmin=camera.min_depth, vmax=np.nanmax(shown) if np.isfinite(shown).any() else 4.5
    )
    if mask is not None and mask.any():
        overlay = np.zeros((*mask.shape, 4))
        overlay[mask] = (1, 1, 1, 0.6)
        ax.imshow(overlay)
    fig.colorbar(im, ax=ax, fraction=0.035, label="depth z [m] (blank = no reading)")
    p = camera.project(centres)
    tip = camera.project(centres + arrow_scale * repulsive)
    cmap = plt.get_cmap("autumn")
    for i, name in enumerate(names):
        d = distances[i]
        colour = cmap(min(d / 0.4, 1.0)) if np.isfinite(d) else (0.6, 0.6, 0.6, 1)
        ax.plot(p[i, 0], p[i, 1], "o", ms=7, mec="k", mfc=colour)
        if np.linalg.norm(repulsive[i]) > 1e-6:
            ax.annotate("", xy=tip[i, :2], xytext=p[i, :2], arrowprops=dict(arrowstyle="->", color="red", lw=2))
        label = f"{name}\n{d:.3f} m" if np.isfinite(d) else name
        ax.text(p[i, 0] + 6, p[i, 1] - 6, label, fontsize=7, color="white")
    ax.set_xlim(0, camera.width)
    ax.set_ylim(camera.height, 0)
    ax.set_title(title or "depth image, control points and repulsive vectors (red)")
    ax.set_xlabel("u [px]")
    ax.set_ylabel("v [px]")
    fig.tight_layout()
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
