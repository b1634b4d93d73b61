"""A background model of the empty cell for speed and separation monitoring in the simulated cell.

SSM protects *people*: the fixed parts of the cell (room, floor, the table the robot stands on) are not
approaching anyone, yet a depth camera sees them like any other surface, and ``S_p`` at rest (about 0.2 m
with the defaults) exceeds the clearance of the arm's lower control points to its own table, so the monitor
would never let the arm move. A real installation records the empty cell once at commissioning and
monitors only what is not background; :class:`BackgroundFilter` does the same here: every camera's depth of
the static geoms (geom group 0: room, floor, table; not the boxes, which stay obstacles) is ray cast once,
and afterwards a pixel whose measured depth is at or behind that background (within the camera's noise:
3 sigma + quantization + 1 cm) reads as the far end of the camera's range: free space in front of it, as in
the empty cell (the rule: :mod:`depthguard.robot.background`, shared with ``depthguard run``'s commissioned
background). (Masking it like a robot pixel would not do: a missing pixel surrounded by masked pixels has
no valid neighbour to be filled from and becomes unknown space, i.e. an obstacle at the near limit.) A
missing pixel next to a person is still filled with the person's, nearer, depth.

Limit: a person flat against the background (a hand lying on the table) is hidden within that tolerance.
"""

from __future__ import annotations

import numpy as np

__all__ = ["BackgroundFilter"]


class BackgroundFilter:
    """Wraps a :class:`~depthguard.sim.pipeline.DistanceStage`; ``update`` adds the background to the masks.

    Args:
        stage: the distance stage.
        cell: the simulated cell (its static geoms are ray cast once, at construction: commissioning).
        cams: the simulated cameras (:class:`~depthguard.sim.depthcam.KinectSim`), same order as the stage's.
        groups: the geom groups that make the background.
        margin: extra tolerance, m.
    """

    def __init__(self, stage, cell, cams, groups: tuple[int, ...] = (0,), margin: float = 0.01) -> None:
        from depthguard.robot.background import background_threshold, far_range
        from depthguard.sim.depthcam import raycast_depth

        self.stage = stage
        self.background_groups = tuple(int(g) for g in groups)  # the truth of the metrics leaves them out
        gg = np.zeros(6, np.uint8)
        gg[list(groups)] = 1
        cell.forward()
        self.far = []  # per camera: depth at or beyond which a pixel is background (inf: never)
        self.beyond = [far_range(c.camera) for c in cams]
        for c in cams:
            ref = raycast_depth(cell.model, cell.data, c.camera, gg)
            self.far.append(background_threshold(ref, c.noise_coeff, c.quantization, margin))

    def __getattr__(self, name: str):
        return getattr(self.stage, name)

    def update(self, depths: list[np.ndarray], masks: list[np.ndarray], *args, **kwargs) -> None:
        """Frame stage: background pixels (not robot pixels) read as the far range, then the wrapped stage."""
        from depthguard.robot.background import apply_background

        out = [  # NaN (no reading) is never background
            apply_background(d, m, far, beyond)
            for d, m, far, beyond in zip(depths, masks, self.far, self.beyond, strict=True)
        ]
        self.stage.update(out, masks, *args, **kwargs)
