"""Multi-camera distance evaluation with the depth grid of Flacco & De Luca (RA-L 2016).

* :class:`DepthGrid`: the principal camera's depth grid (eq. 4, §III);
* :class:`GridMap`: the off-line map between the cameras (§V), stored or computed on the fly;
* :class:`DepthGridFusion`: the on-line fusion (§VI cases i-iii, §VII case iv) and the min / all /
  hybrid aggregations (ICRA'12 eq. 9, RA-L'16 eq. 11);
* :func:`fused_distances`: one-shot helper for the command line.
"""

from depthguard.depthgrid.fusion import DepthGridFusion
from depthguard.depthgrid.grid import DepthGrid, workspace_depth_range
from depthguard.depthgrid.gridmap import MAP_MODES, GridMap
from depthguard.depthgrid.oneshot import fused_distances

__all__ = ["DepthGrid", "DepthGridFusion", "GridMap", "MAP_MODES", "fused_distances", "workspace_depth_range"]
