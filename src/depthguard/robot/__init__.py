"""Robot layer: URDF models through pinocchio (:mod:`~depthguard.robot.model`), their collision geometry
(:mod:`~depthguard.robot.shapes`, :mod:`~depthguard.robot.geometry`: meshes, primitives, attached tools),
control-point spheres (:mod:`~depthguard.robot.control_points`, :mod:`~depthguard.robot.spheres`) and the
self-filter (:mod:`~depthguard.robot.selffilter`).

The shipped 7-DOF KUKA LWR IV-like arm is :func:`depthguard.robot.model.load_lwr4`; the tested arms of
example-robot-data load with :func:`depthguard.robot.robots.load_robot`. pinocchio is imported when a
model is built, not when this package is imported.
"""
