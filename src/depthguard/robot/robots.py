"""Named robots: the shipped LWR and arms of the installed ``example-robot-data`` package.

``load_robot("panda")`` etc. return a :class:`depthguard.robot.model.RobotModel` whose collision meshes are
resolved from the package (found through ``importlib.metadata``, not a fixed path). The tested arms are
listed in :data:`ROBOTS`; any other URDF loads with :meth:`RobotModel.from_urdf`.
"""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

__all__ = ["ROBOTS", "load_robot", "robot_data_dir", "robot_urdf"]

# name -> (URDF path inside example-robot-data/robots, end-effector frame)
ROBOTS: dict[str, tuple[str, str]] = {
    "panda": ("panda_description/urdf/panda.urdf", "panda_hand"),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", "tool0"),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", "link7"),
    # Kinova Jaco2 6-DOF (j2s6s200): joints 1, 4 and 6 are continuous (unbounded angles)
    "kinova": ("kinova_description/robots/kinova.urdf", "j2s6s200_end_effector"),
}


def robot_data_dir() -> Path:
    """The ``share/example-robot-data`` folder of the installed robot-data package."""
    try:
        dist = metadata.distribution("example-robot-data")
    except metadata.PackageNotFoundError as e:
        raise ValueError("robot 'example-robot-data' is not installed (pip install 'depthguard[robot]')") from e
    path = Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data")))
    if not path.is_dir():
        raise ValueError(f"example-robot-data: folder {path} not found")
    return path


def robot_urdf(name: str) -> Path:
    """URDF path of ``"lwr4"`` (shipped) or a named robot of :data:`ROBOTS`."""
    if name == "lwr4":
        from depthguard.robot.model import lwr4_urdf_path

        return lwr4_urdf_path()
    if name not in ROBOTS:
        raise ValueError(f"unknown robot '{name}'; known: {['lwr4', *sorted(ROBOTS)]}")
    return robot_data_dir() / "robots" / ROBOTS[name][0]


def load_robot(name: str, **kwargs):
    """A :class:`RobotModel` by name: ``"lwr4"`` (shipped) or one of :data:`ROBOTS`; ``kwargs`` go to
    :meth:`RobotModel.from_urdf` (``attachments``, ``max_triangles``, ...)."""
    from depthguard.robot.model import RobotModel, load_lwr4

    if name == "lwr4":
        model = load_lwr4()
        if kwargs.get("attachments"):
            model.attach(*kwargs["attachments"])
        return model
    path = robot_urdf(name)
    return RobotModel.from_urdf(path, ee_frame=kwargs.pop("ee_frame", ROBOTS[name][1]), **kwargs)
