"""DepthGuard's own ROS 2 interface package, ``depthguard_msgs``, written out for a ROS 2 workspace.

The nodes publish their distances and status as ``depthguard_msgs`` messages (:data:`DEPTHGUARD_MSGS`). A
ROS 2 node sees those topics in ``ros2 topic list`` without anything more, but to echo or subscribe to them
it needs the interface package built in its workspace. :func:`write_msgs_package` writes it from the same
definitions that DepthGuard serialises with (one source: no drift), as an ament_cmake / rosidl package:
``package.xml``, ``CMakeLists.txt`` and ``msg/*.msg``. ``depthguard ros2-msgs --out ~/ros2_ws/src`` then
``colcon build --packages-select depthguard_msgs``.

The type hashes that rmw_zenoh puts in the topics' key expressions (``RIHS01_...``) follow from these
definitions; :func:`write_msgs_package` returns them so that a built package can be compared with
``ros2 topic info -v``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from depthguard.io.ros2 import DEPTHGUARD_MSGS

__all__ = ["PACKAGE", "write_msgs_package", "package_files"]

PACKAGE = "depthguard_msgs"
_DEPENDS = ("std_msgs", "geometry_msgs")


def _package_xml(version: str) -> str:
    deps = "\n".join(f"  <depend>{d}</depend>" for d in _DEPENDS)
    return f"""<?xml version="1.0"?>
<?xml-model href="http://download.ros.org/schema/package_format3.xsd" schematypens="http://www.w3.org/2001/XMLSchema"?>
<package format="3">
  <name>{PACKAGE}</name>
  <version>{version}</version>
  <description>
    DepthGuard's messages: control-point distances to obstacles and the avoidance controller's status
    (written by depthguard ros2-msgs).
  </description>
  <maintainer email="depthguard@example.org">DepthGuard</maintainer>
  <license>BSD-3-Clause</license>

  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
{deps}
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>

  <export>
    <build_type>ament_cmake</build_type>
  </export>
</package>
"""


def _cmakelists(msgs: list[str]) -> str:
    files = "\n".join(f'  "msg/{m}.msg"' for m in msgs)
    finds = "\n".join(f"find_package({d} REQUIRED)" for d in _DEPENDS)
    return f"""cmake_minimum_required(VERSION 3.8)
project({PACKAGE})

find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
{finds}

rosidl_generate_interfaces(${{PROJECT_NAME}}
{files}
  DEPENDENCIES {" ".join(_DEPENDS)}
)

ament_export_dependencies(rosidl_default_runtime)
ament_package()
"""


def package_files(version: str) -> dict[str, str]:
    """Relative path -> text of every file of the package."""
    msgs = {name.rsplit("/", 1)[1]: text for name, text in DEPTHGUARD_MSGS.items()}
    out = {f"msg/{m}.msg": text for m, text in msgs.items()}
    out["package.xml"] = _package_xml(version)
    out["CMakeLists.txt"] = _cmakelists(sorted(msgs))
    return out


def write_msgs_package(out_dir: str | Path, *, overwrite: bool = False) -> dict[str, Any]:
    """Write ``out_dir/depthguard_msgs`` (a ROS 2 workspace's ``src`` folder, say).

    Returns ``folder``, ``files`` (relative paths) and ``type_hashes`` (type name -> ``RIHS01_...``).
    Raises ``ValueError`` when the package folder holds other files and ``overwrite`` is not set.
    """
    from depthguard import __version__
    from depthguard.io.rmw_zenoh import type_hash

    folder = Path(out_dir).expanduser() / PACKAGE
    files = package_files(__version__)
    existing = [p for p in files if (folder / p).exists()]
    if existing and not overwrite:
        raise ValueError(f"{folder} already holds {existing[0]} (and {len(existing) - 1} more): use --overwrite")
    for rel, text in files.items():
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return {
        "folder": str(folder),
        "files": sorted(files),
        "type_hashes": {name: type_hash(name) for name in DEPTHGUARD_MSGS},
    }
