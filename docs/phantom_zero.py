"""Draws docs/phantom_zero.png: the space that two Kinects leave unmeasured next to the arm
(see docs/phantom-zero.md).

The ``ral-hexagon`` cell without its person, the arm at the hexagon's waypoint (0.5, -0.2, 0.55), 160x120
Kinects. Left: the principal camera (orange: robot pixels; +: where the shoulder's control sphere finds
its nearest "obstacle"). Middle: the second camera (red: no reading, the projector's shadow; the box:
the footprint of the cell that it cannot clear). Right: evaluated distance of every control point with
two and with three cameras, against the true clearance.

    PYTHONPATH=src python docs/phantom_zero.py
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from depthguard.sim import scenario_setup as setup  # noqa: E402
from depthguard.sim import scenarios as S  # noqa: E402
from depthguard.sim.cell import CellSpec, build_cell  # noqa: E402
from depthguard.sim.depthcam import KinectSim, placement  # noqa: E402
from depthguard.sim.pipeline import DistanceStage, filter_margin, self_filter  # noqa: E402
from depthguard.sim.pointtruth import PointClearance  # noqa: E402

OUT = Path(__file__).with_name("phantom_zero.png")
WAYPOINT = (0.5, -0.2, 0.55)


def _evaluate(cams, q, kin):
    cell = build_cell(CellSpec(cameras=cams, q0=tuple(q), floor_z=-0.8, room=(-1.1, 2.0, -1.1, 2.0)))
    sims = [KinectSim(cell.model, c, i, seed=i) for i, c in enumerate(cams)]
    cell.forward()
    depths = [s.capture(cell.data) for s in sims]
    margins = [filter_margin(s.camera, q, kin, s.noise_coeff) for s in sims]
    masks = [self_filter(s.camera, d, q, kin, margin=m) for s, d, m in zip(sims, depths, margins, strict=True)]
    stage = DistanceStage(cams, rho=0.4, mode="hybrid")
    stage.update(depths, masks, q, kin, margins)
    cp = kin.evaluate(q)
    pc = PointClearance(cell)
    truth, _ = pc.evaluate(cp.centres, cp.radii, pc.snapshot(cell.data))
    return stage.query(cp.centres, cp.radii), truth, depths, masks


def _px(cam, p):
    x = cam.world_to_camera(np.asarray(p)[None])[0]
    return cam.fx * x[0] / x[2] + cam.cx, cam.fy * x[1] / x[2] + cam.cy


def main(out: Path = OUT) -> Path:
    sc = S.load_scenario("ral-hexagon")
    _, kin, _ = setup.build_scenario_cell(sc, quick=True, cameras=2)
    q = setup.solve_ik(kin, np.array(sc["q0"], float), np.asarray(WAYPOINT, float))
    cams3 = placement("ral3", 160, 120)
    two, truth, depths, masks = _evaluate(cams3[:2], q, kin)
    three, _, _, _ = _evaluate(cams3, q, kin)
    i = kin.names.index("lwr_link_2/0")
    p = np.asarray(two.nearest[i])

    fig, ax = plt.subplots(1, 3, figsize=(15, 4.6))
    for k in range(2):
        d = depths[k]
        ax[k].imshow(np.where(np.isfinite(d), d, np.nan), cmap="gray_r", vmin=1.0, vmax=4.5)
        ax[k].imshow(np.ma.masked_where(~masks[k], masks[k]), cmap="Oranges", alpha=0.35, vmin=0, vmax=1.5)
        vv, uu = np.nonzero(~np.isfinite(d) & ~masks[k])
        ax[k].scatter(uu, vv, s=3, c="red", label="no reading (projector shadow)")
        u, v = _px(cams3[k], p)
        ax[k].plot(u, v, "b+", ms=14, mew=2, label="nearest 'obstacle' of the shoulder sphere")
        ax[k].legend(fontsize=7, loc="lower left")
    ax[0].set_title("principal camera: the point lies behind the arm", fontsize=9)
    ax[1].set_title("second camera: its ray runs in the shadow of the table's corner", fontsize=9)
    x = np.arange(len(kin.names))
    ax[2].bar(x - 0.27, np.minimum(two.distance, 0.4), 0.27, label="evaluated, 2 cameras")
    ax[2].bar(x, np.minimum(three.distance, 0.4), 0.27, label="evaluated, 3 cameras")
    ax[2].bar(x + 0.27, np.minimum(truth, 0.4), 0.27, label="true clearance")
    ax[2].set_xticks(x, [n.replace("lwr_", "") for n in kin.names], rotation=45, fontsize=7)
    ax[2].set_ylabel("distance from the sphere's surface [m] (capped at ρ)")
    ax[2].legend(fontsize=7)
    ax[2].set_title(f"no person, arm at {WAYPOINT} (160x120)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


if __name__ == "__main__":
    print(main())
