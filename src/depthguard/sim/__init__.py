"""The simulated work cell (MuJoCo 4, optional extra ``sim``): the papers' experiments end to end.

* :mod:`depthguard.sim.cell`: the arm (from the robot's URDF), table, room, boxes, capsule people, cameras;
* :mod:`depthguard.sim.people`: scripted capsule people (keyframes from scenario files);
* :mod:`depthguard.sim.depthcam`: simulated Kinect v1 (``mj_multiRay`` or OpenGL, noise, range, edges);
  :mod:`depthguard.sim.raysplit`: its ray casting with the room cast once;
* :mod:`depthguard.sim.truth`: true clearances (``mj_geomDistance``), for metrics only;
* :mod:`depthguard.sim.pipeline`: adapters to the pipeline (robot model, self-filter, distances, fusion,
  controller);
* :mod:`depthguard.sim.loop`: the three rates (30 Hz frames, 333 Hz distances, 1 kHz control) in simulated time;
* :mod:`depthguard.sim.scenarios`: scenario files, :func:`~depthguard.sim.scenarios.run_scenario`, metrics;
* :mod:`depthguard.sim.recorder`: MCAP recordings (Foxglove); :mod:`depthguard.sim.demo`: ``make demo``.

Nothing here is imported by the core: ``import depthguard.sim`` does not import MuJoCo.
"""
