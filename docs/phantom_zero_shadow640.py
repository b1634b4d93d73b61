"""Draws docs/phantom_zero_shadow640.png: the one pixel behind the 0.06 s at zero of ``ral-shadow`` at 640x480
with two cameras (see docs/phantom-zero.md, fifth round).

Runs the scenario (its "ral-rolled" cameras, closed loop, avoidance on) to the frame at t = 1.0 s, then
draws both depth images: the principal camera, where the panel the person holds hides the end effector's
control sphere (white circle), and the second camera, where the ray of one pixel without a reading (the
Kinect's projector shadow of a 3.33 m edge over a 3.66 m surface) passes through that sphere (dashed in
the principal view). That ray is space that neither camera measures, so the sphere reads 0 there.

    PYTHONPATH=src python docs/phantom_zero_shadow640.py      (about 20 s)
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.patches import Circle, Rectangle  # noqa: E402

import depthguard.sim.loop as loop  # noqa: E402
from depthguard.sim.scenarios import run_scenario  # noqa: E402

OUT = Path(__file__).with_name("phantom_zero_shadow640.png")
T_FRAME = 1.0  # s, the frame whose end-effector sphere reads 0
HOLE = (401, 121)  # (u, v) of the second camera's pixel without a reading (found by the measured bound's lattice)


class _Captured(Exception):
    pass


def capture() -> dict:
    """The frame set at ``T_FRAME``: cameras, depth images and the end effector's control sphere."""
    original = loop._frame_stage
    count = [0]

    def hooked(cell, cams, kin, stage, q_meas, log):
        out = original(cell, cams, kin, stage, q_meas, log)
        t = count[0] / 30.0
        count[0] += 1
        if abs(t - T_FRAME) < 1e-6:
            cp = kin.evaluate(q_meas)
            raise _Captured(dict(cams=[c.camera for c in cams], depths=out[0], c=cp.centres[0], r=cp.radii[0]))
        return out

    loop._frame_stage = hooked
    try:
        run_scenario("ral-shadow", cameras=2, variants=False)
    except _Captured as done:
        return done.args[0]
    finally:
        loop._frame_stage = original
    raise RuntimeError("the run ended before the frame")


def draw(f: dict) -> None:
    P, S = f["cams"]
    c, r = f["c"], f["r"]
    ray = S.unproject(np.full(60, HOLE[0] + 0.5), np.full(60, HOLE[1] + 0.5), np.linspace(1.8, 3.6, 60))
    fig, ax = plt.subplots(1, 3, figsize=(15, 4.2))

    def show(a, cam, img, title, box=None):
        im = a.imshow(np.where(np.isfinite(img), img, np.nan), cmap="viridis", vmin=0.5, vmax=4.5)
        a.set_facecolor("red")
        pc = cam.R @ c + cam.t
        u, v = cam.fx * pc[0] / pc[2] + cam.cx, cam.fy * pc[1] / pc[2] + cam.cy
        a.add_patch(Circle((u, v), cam.fx * r / pc[2], fill=False, ec="white", lw=1.5))
        pr = cam.project(ray)
        a.plot(pr[:, 0], pr[:, 1], "w--", lw=1)
        a.set_title(title, fontsize=9)
        box = box or (0, cam.width, 0, cam.height)
        a.set_xlim(box[0] - 0.5, box[1] - 0.5)
        a.set_ylim(box[3] - 0.5, box[2] - 0.5)
        return im

    show(
        ax[0],
        P,
        f["depths"][0],
        "principal camera, t = 1.00 s: the panel (0.89 m)\nhides the end effector's sphere (white);\n"
        "dashed: the second camera's ray without a reading",
    )
    show(
        ax[1],
        S,
        f["depths"][1],
        "second camera (on its side):\nthe end effector's sphere (white),\nthe pixel without a reading (red box)",
    )
    ax[1].add_patch(Rectangle((HOLE[0] - 12, HOLE[1] - 12), 25, 25, fill=False, ec="red", lw=1))
    im = show(
        ax[2],
        S,
        f["depths"][1],
        "second camera, 25x25 pixels around it:\none pixel in the projector shadow\n"
        "of a 3.33 m edge over a 3.66 m surface",
        (HOLE[0] - 12, HOLE[0] + 13, HOLE[1] - 12, HOLE[1] + 13),
    )
    fig.colorbar(im, ax=ax, shrink=0.8, label="depth [m] (red: no reading)")
    fig.savefig(OUT, dpi=90, bbox_inches="tight")


if __name__ == "__main__":
    draw(capture())
    print(OUT)
