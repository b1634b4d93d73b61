"""DepthGuard: depth-space human-robot collision avoidance.

Implements Flacco et al., "A Depth Space Approach to Human-Robot Collision Avoidance" (ICRA 2012),
Flacco & De Luca, "Real-Time Computation of Distance to Dynamic Obstacles With Multiple Depth Sensors"
(IEEE RA-L 2016), and the close-range monitoring methods of SAPHARI D4.1.1.
"""

from pathlib import Path

from depthguard.kernelcache import use_versioned_cache

use_versioned_cache(Path(__file__).parent)  # before any kernel module is imported (depthguard.kernelcache)

from depthguard.camera import Camera, look_at  # noqa: E402

__version__ = "0.1.0"
__all__ = ["Camera", "look_at", "__version__"]
