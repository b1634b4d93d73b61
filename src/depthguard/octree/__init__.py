"""Close-range obstacle octree of SAPHARI D4.1.1 §3: reachability grid, per-sensor node sets and their fusion,
robot-to-octree minimum distance. Core maths (numpy/numba); ``coal`` and ``pyoctomap`` are optional."""
