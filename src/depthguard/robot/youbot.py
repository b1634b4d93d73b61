"""The youBot-like mobile manipulator and its ten proximity sensors (SAPHARI D4.1.1 §5.3).

:func:`load_youbot` loads the shipped URDF (``data/youbot/youbot.urdf``; dimensions and their sources in
its header): 8 DOF numbered as in the paper, base ``x``, ``y`` (prismatic, m), ``theta`` (rad), then the
arm's five joints. Link 3 is the platform, links 4-8 the arm's DH frames.

:data:`YOUBOT_SENSORS` are the ten Sharp sensors of eqs. 5.13 (positions, cm in the paper) and 5.14
(optical axes) on links ``l = [3, 3, 3, 3, 5, 7, 7, 3, 3, 6]``: six GP2Y0A21YK (80 cm) on the base and
four GP2D120XJ00F (30 cm) on the arm. The third row of eq. 5.14 lost an entry in the text; by unit norm
it is ``0 0 0 0 1 0.2 0 0 0 -1`` (sensor 6's axis (0, 0.98, 0.2) is unit to 2 %; it is normalised here).
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from depthguard.robot.model import RobotModel
from depthguard.sensors.mount import SensorMount
from depthguard.sensors.sharp import GP2D120XJ00F, GP2Y0A21YK

__all__ = ["youbot_urdf_path", "load_youbot", "YOUBOT_SENSORS", "YOUBOT_Q0", "LINK_FRAMES", "ee_point"]

#: Paper link index -> frame of the shipped URDF.
LINK_FRAMES = {3: "platform", 4: "link4", 5: "link5", 6: "link6", 7: "link7", 8: "link8"}

_P_CM = np.array(
    [
        [16, 23, 10, -4, -7, 0, 4, -29, -29, 0],
        [-11, 0, -16, -16, -2, 6, 0, -13, 13, 0],
        [0, 0, 4, 0, 8, 4, 7, 5, 5, -8],
    ],
    float,
)
_S2, _S3 = np.sqrt(2) / 2, np.sqrt(3) / 2
_V = np.array(
    [
        [_S2, 1, 0.5, 0, 0, 0, 1, -_S2, -_S2, 0],
        [-_S2, 0, -_S3, -1, 0, 0.98, 0, -_S2, _S2, 0],
        [0, 0, 0, 0, 1, 0.2, 0, 0, 0, -1],
    ],
    float,
)
_L = [3, 3, 3, 3, 5, 7, 7, 3, 3, 6]


def _mounts() -> tuple[SensorMount, ...]:
    out = []
    for k in range(10):
        model = GP2Y0A21YK if _L[k] == 3 else GP2D120XJ00F
        v = _V[:, k] / np.linalg.norm(_V[:, k])
        out.append(
            SensorMount(
                name=f"s{k + 1}",
                link=LINK_FRAMES[_L[k]],
                position=tuple(_P_CM[:, k] / 100.0),
                axis=tuple(v),
                max_range=model.d_max,
                kind=model.name,
            )
        )
    return tuple(out)


#: The ten sensors of eqs. 5.13-5.14 (positions converted to m).
YOUBOT_SENSORS: tuple[SensorMount, ...] = _mounts()

#: Initial configuration of the place task: base at the origin, gripper horizontal and forward, the end
#: effector at about (0.45, 0, 0.45) m; no sensor sees the robot (tests/test_saphari_nsb.py).
YOUBOT_Q0 = np.array([0.0, 0.0, 0.0, 0.0, 0.55, -1.55, -0.57, 0.0])


def youbot_urdf_path() -> Path:
    """Path of the shipped youBot-like URDF."""
    return Path(str(resources.files("depthguard.robot") / "data" / "youbot" / "youbot.urdf"))


def load_youbot() -> RobotModel:
    """The youBot-like robot (8 DOF); end effector = ``link8`` (the finger tips)."""
    return RobotModel(youbot_urdf_path(), ee_frame="link8")


def ee_point() -> np.ndarray:
    """(3,) end-effector point in ``link8``: between the finger tips, m."""
    return np.zeros(3)
