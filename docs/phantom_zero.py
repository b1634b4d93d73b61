"""Draws docs/phantom_zero.png: why the demo's evaluated distance dropped to 0 (see docs/phantom-zero.md).

Runs the quick ral-hexagon scenario with two cameras to t = 3 s, then shows, at that frame, the principal
camera's robot pixels without a reading (the depth-edge band along the arm), the second camera's view
with the parcel in front of the arm, and the evaluated distance of every control point before and after
the corrections of depthguard.robot.interior, against the true clearance.

    PYTHONPATH=src python docs/phantom_zero.py
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from depthguard.depthgrid import DepthGridFusion  # noqa: E402
from depthguard.robot.interior import principal_robot_pixels, robot_windows  # noqa: E402
from depthguard.sim import scenarios as S  # noqa: E402
from depthguard.sim.depthcam import KinectSim  # noqa: E402
from depthguard.sim.loop import LoopConfig, run_loop  # noqa: E402
from depthguard.sim.pipeline import Controller, DistanceStage, self_filter  # noqa: E402
from depthguard.sim.pointtruth import PointClearance  # noqa: E402

T = 3.0


OUT = Path(__file__).with_name("phantom_zero.png")


def main(out: Path = OUT) -> Path:
    sc = S.load_scenario("ral-hexagon")
    sc["quick_duration"] = T
    cell, kin, ee0 = S._build(sc, quick=True, cameras=2)
    cams = [KinectSim(cell.model, c, i, seed=i) for i, c in enumerate(cell.cameras)]
    ws = (-1.2, 1.2, -1.2, 1.2, -0.3, 1.5)
    stage = DistanceStage(cell.cameras, rho=0.4, mode="hybrid", workspace=ws)
    ctrl = Controller(kin, cell.q(), rho=0.4, vmax=1.0, alpha=6.0, rho_body=0.3, alpha_body=6.0)
    run_loop(cell, cams, kin, stage, ctrl, S._task(sc, ee0), LoopConfig(duration=T, vmax=1.0))
    cell.forward()
    q = cell.q()
    depths = [c.capture(cell.data) for c in cams]
    masks = [self_filter(c.camera, d, q, kin)[0] for c, d in zip(cams, depths, strict=True)]
    cp = kin.evaluate(q)
    truth, _ = PointClearance(cell).evaluate(cp.centres, cp.radii, PointClearance(cell).snapshot(cell.data))
    before = DepthGridFusion(cell.cameras, dd=0.01, workspace=ws)
    before.update(depths, masks)
    a, b, r = kin.capsules(q)
    d0, m0 = principal_robot_pixels(cell.cameras[0], depths[0], masks[0], a, b, r)
    after = DepthGridFusion(cell.cameras, dd=0.01, workspace=ws)
    after.update([d0, depths[1]], [m0, masks[1]], windows=[None, robot_windows(cell.cameras[1], a, b, r)])
    eb = before.query(cp.centres, cp.radii, rho=0.4, mode="hybrid")
    ea = after.query(cp.centres, cp.radii, rho=0.4, mode="hybrid")

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.6))
    band = masks[0] & ~np.isfinite(depths[0])
    ax[0].imshow(np.where(np.isfinite(depths[0]), depths[0], np.nan), cmap="gray_r", vmin=1.0, vmax=4.5)
    ax[0].imshow(np.ma.masked_where(~masks[0], masks[0]), cmap="Oranges", alpha=0.35, vmin=0, vmax=1.5)
    vv, uu = np.nonzero(band)
    ax[0].scatter(uu, vv, s=4, c="red", label="robot pixels without a reading (edge band)")
    for p in eb.nearest[np.asarray(eb.distance) <= 0.005]:
        c0 = cell.cameras[0]
        pc = c0.world_to_camera(p[None])[0]
        ax[0].plot(c0.fx * pc[0] / pc[2] + c0.cx, c0.fy * pc[1] / pc[2] + c0.cy, "b+", ms=12)
    ax[0].set_title("principal camera (orange: robot mask; +: the 'obstacles' at 0)", fontsize=9)
    ax[0].legend(fontsize=7, loc="lower left")
    ax[1].imshow(np.where(np.isfinite(depths[1]), depths[1], np.nan), cmap="gray_r", vmin=1.0, vmax=4.5)
    ax[1].imshow(np.ma.masked_where(~masks[1], masks[1]), cmap="Oranges", alpha=0.35, vmin=0, vmax=1.5)
    for p in eb.nearest[np.asarray(eb.distance) <= 0.005]:
        c1 = cell.cameras[1]
        pc = c1.world_to_camera(p[None])[0]
        ax[1].plot(c1.fx * pc[0] / pc[2] + c1.cx, c1.fy * pc[1] / pc[2] + c1.cy, "b+", ms=12)
    ax[1].set_title("second camera: the parcel lies in front of those points", fontsize=9)
    x = np.arange(len(cp.radii))
    ax[2].bar(x - 0.27, np.minimum(eb.distance, 0.4), 0.27, label="evaluated, before")
    ax[2].bar(x, np.minimum(ea.distance, 0.4), 0.27, label="evaluated, after")
    ax[2].bar(x + 0.27, np.minimum(truth, 0.4), 0.27, label="true clearance")
    ax[2].set_xticks(x, [n.replace("lwr_", "") for n in kin.names], rotation=45, fontsize=7)
    ax[2].set_ylabel("distance from the sphere's surface [m] (capped at ρ)")
    ax[2].legend(fontsize=7)
    ax[2].set_title(f"control points at t = {T:.1f} s (160x120)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(main())
