"""Robot layer: URDF models through pinocchio (:mod:`~depthguard.robot.model`), control-point spheres
(:mod:`~depthguard.robot.control_points`) and the self-filter (:mod:`~depthguard.robot.selffilter`).

The shipped 7-DOF KUKA LWR IV-like arm is :func:`depthguard.robot.model.load_lwr4`. pinocchio is
imported when a model is built, not when this package is imported.
"""
