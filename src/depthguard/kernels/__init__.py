"""Numba kernel parts shared by the single-camera (:mod:`depthguard.depthspace`) and the depth-grid
(:mod:`depthguard.depthgrid`) distance queries.

* :mod:`depthguard.kernels.records`: the typed parameter records passed to the kernels;
* :mod:`depthguard.kernels.region`: the unseen space, the region of surveillance and the tile lower bounds;
* :mod:`depthguard.kernels.hits`: the aggregation of obstacle hits into distance, direction, nearest point
  and count (min / all / hybrid modes, ICRA'12 eq. 9, RA-L'16 eq. 11).

Every kernel uses :data:`FASTMATH`: fast-math without the no-NaN / no-inf assumptions, because +inf marks
"nothing" in the depth images, tile minima and vote images (``tests/test_kernel_nonfinite.py``).
Conventions (frames, units, the lower-bound and missing-depth rules): ``docs/conventions.md``.
"""

FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

__all__ = ["FASTMATH"]
