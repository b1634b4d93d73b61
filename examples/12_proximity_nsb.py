"""NSB control with robot-mounted proximity sensors, without a simulator (SAPHARI D4.1.1 §5).

The youBot-like robot holds its end effector still while a low obstacle (a kerb, the plane x = 0.36 m,
lower than the arm) stands just in front of its base. The front base sensor (sensor 2, a Sharp
GP2Y0A21YK) measures the range to it along its optical axis analytically; the NSB controller
(eqs. 5.4-5.12) backs the base off to relax that sensor's spring while the arm stretches to keep the end
effector near where it was. Then the skin's safety levels: a hand approaching at 0.25 m/s, one
Gray-coded level per update.

Run: ``python examples/12_proximity_nsb.py``
"""

import numpy as np

from depthguard.control.nsb import NSBConfig, NSBController
from depthguard.robot.youbot import YOUBOT_Q0, YOUBOT_SENSORS, load_youbot
from depthguard.sensors import LevelMap, LevelStepper, ProximityTaxel, gray_encode, hold_time

robot = load_youbot()
ctrl = NSBController(robot, YOUBOT_SENSORS, NSBConfig(rest=0.2, f=0.15, lambda_kind="arctan"))
q = YOUBOT_Q0.copy()
x_hold = ctrl.sensors.evaluate(q).ee_position
wall_x = 0.36
for k in range(900):  # 3 s at the sensors' 300 Hz
    st = ctrl.sensors.evaluate(q)
    d = np.full(10, np.inf)
    for s in range(10):  # range along each optical axis to the plane x = wall_x, within the sensor's range
        ax = st.axes[s, 0]
        if ax > 1e-6:
            r = (wall_x - st.positions[s, 0]) / ax
            if 0 <= r <= YOUBOT_SENSORS[s].max_range:
                d[s] = r
    out = ctrl.step(q, x_hold, np.zeros(3), d)
    if k % 150 == 0:
        print(
            f"t = {k / 300:4.2f} s  d2 = {d[1]:.3f} m  sigma = {out.sigma:.5f} m^2  lambda = {out.lam:.2f}  "
            f"base x = {q[0]:+.3f} m  ee error = {np.linalg.norm(out.ee - x_hold) * 1e3:.1f} mm"
        )
    q = out.q_next

prox = ProximityTaxel(noise_counts=0.0)
lmap = LevelMap(tuple(prox.counts_at(x) for x in (0.05, 0.04, 0.032, 0.025, 0.02, 0.016)))
stepper = LevelStepper(hold=hold_time(line_skew=4.4e-3, sample_period=2e-3))
print("hand at 0.25 m/s: t [ms], distance [mm], level, Gray code on the lines")
for ms in range(0, 300, 4):
    dist = max(0.06 - 0.25 * ms / 1000, 0.0)
    level, wrote = stepper.update(ms / 1000, lmap.update(float(prox.counts(np.array([dist]))[0]), dist <= 0.0))
    if wrote:
        print(f"  {ms:4d}  {dist * 1e3:5.1f}  {level}  {int(gray_encode(level)):03b}")
