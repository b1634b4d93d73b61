"""A background model of the empty cell for speed and separation monitoring in the simulated cell.

SSM protects *people*: the fixed parts of the cell (room, floor, the table the robot stands on) are not
approaching anyone, yet a depth camera sees them like any other surface, and ``S_p`` at rest (about 0.2 m
with the defaults) exceeds the clearance of the arm's lower control points to its own table, so the monitor
would never let the arm move. A real installation records the empty cell once at commissioning and
monitors only what is not background; :func:`background_stages` does the same here: every camera's depth of
the static cell (geom group 0: room, floor, table; and the fixed boxes, fixtures such as the shelf box of
``icra-exp3``; not the movable boxes and carried objects, which stay obstacles) is ray cast once,
and afterwards a pixel whose measured depth is at or behind that background (within the camera's noise:
3 sigma + quantization + 1 cm) reads as the far end of the camera's range: free space in front of it, as in
the empty cell (the rule: :mod:`depthguard.robot.background`, shared with ``depthguard run``'s commissioned
background). (Masking it like a robot pixel would not do: a missing pixel surrounded by masked pixels has
no valid neighbour to be filled from and becomes unknown space, i.e. an obstacle at the near limit.) A
missing pixel next to a person is still filled with the person's, nearer, depth.

The background is the *monitor's* only: :func:`background_stages` returns a
:class:`~depthguard.robot.background.MonitorBackgroundStage`, two distance stages on the same frames, so the
repulsion and the body bounds still see (and avoid) the table and the fixtures, while the monitor, which
protects people, does not stop for them.

Limit: a person flat against the background (a hand lying on the table) is hidden within that tolerance.
"""

from __future__ import annotations

import numpy as np

from depthguard.sim.cell import GROUP_BOX, GROUP_ENV

__all__ = ["background_stages", "fixture_names"]


def fixture_names(cell) -> tuple[str, ...]:
    """Names of the cell's fixed boxes (the fixtures that commissioning records with the empty cell)."""
    return tuple(b.name for b in cell.spec.boxes if not b.movable)


def background_stages(stage, monitor, cell, cams, margin: float = 0.01):
    """The repulsion's ``stage`` and the monitor's ``monitor`` (two :class:`~depthguard.sim.pipeline.DistanceStage`
    on the same cameras) as one :class:`~depthguard.robot.background.MonitorBackgroundStage` whose monitor sees
    the frames without the static cell (module docstring). ``cams``: the simulated cameras
    (:class:`~depthguard.sim.depthcam.KinectSim`), same order as the stages'; the static cell is ray cast once,
    here (commissioning), with its fixed boxes; ``margin``: extra tolerance, m."""
    from depthguard.robot.background import MonitorBackgroundStage, background_threshold, far_range
    from depthguard.sim.depthcam import raycast_depth

    env = np.zeros(6, np.uint8)
    env[GROUP_ENV] = 1
    boxes = np.zeros(6, np.uint8)
    boxes[GROUP_BOX] = 1
    names = set(fixture_names(cell))
    fixed = np.array([g for g in range(cell.model.ngeom) if cell.geom_names[g] in names], np.int32)
    cell.forward()
    thresholds = []
    for c in cams:
        ref = raycast_depth(cell.model, cell.data, c.camera, env)
        if len(fixed):  # a fixture where a movable box hides it stays an obstacle (the safe side)
            d, gid = raycast_depth(cell.model, cell.data, c.camera, boxes, return_geoms=True)
            ref = np.fmin(ref, np.where(np.isin(gid, fixed), d, np.nan))
        thresholds.append(background_threshold(ref, c.noise_coeff, c.quantization, margin))
    return MonitorBackgroundStage(stage, monitor, thresholds, [far_range(c.camera) for c in cams])
