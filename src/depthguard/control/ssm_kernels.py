"""Compiled kernels of the speed and separation monitor (:mod:`depthguard.control.ssm`, whose docstring gives
the formulas): the protective separation of every control point at a speed scale (``_s_p``), the largest
allowed scale by bisection (``_largest_scale``), the report for *now* (``_to_now``) and one update (``_update``).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from depthguard.control.braking import stop_one


@njit(cache=True, nogil=True)
def _s_p(s, lever0, lengths, appr_cur, appr_nom, v_cur, a_cur, v_nom, a_max, j_max, v_h_meas, prm, out):
    """S_p,k(s) for all points into ``out`` (N,); returns T_s. ``prm`` = (T_r, C+Z_d+Z_r, v_near, v_far,
    near_limit, v_floor)."""
    n = v_cur.shape[0]
    N = lever0.shape[0]
    travel = np.empty(n)
    T_s = 0.0
    for j in range(n):
        v = max(abs(v_cur[j]), s * abs(v_nom[j]))
        if v_cur[j] == 0.0 or s * abs(v_nom[j]) > abs(v_cur[j]):
            a = abs(a_cur[j])  # direction unknown: take the acceleration as speeding the joint up
        else:
            a = a_cur[j] if v_cur[j] > 0.0 else -a_cur[j]  # relative to the direction of motion
        t, d = stop_one(v, a, a_max[j], j_max[j])
        travel[j] = d
        T_s = max(T_s, t)
    T_r, const, v_near, v_far, near_limit, v_floor = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5]
    for k in range(N):
        S_s = 0.0
        after = 0.0  # sum over joints after j of L_ki travel_i
        for j in range(n - 1, -1, -1):
            lev = min(lengths[k, j], lever0[k, j] + after)
            S_s += lev * travel[j]
            if travel[j] > 0.0:  # (a prismatic joint without limits has an infinite L; inf * 0 is NaN)
                after += lengths[k, j] * travel[j]
        v_r = max(appr_cur[k], s * appr_nom[k])
        rest = v_r * T_r + S_s + const
        if v_h_meas[k] >= 0.0:
            out[k] = max(v_h_meas[k], v_floor) * (T_r + T_s) + rest
        else:
            near = v_near * (T_r + T_s) + rest
            out[k] = near if near <= near_limit else max(v_far * (T_r + T_s) + rest, near_limit)
    return T_s


@njit(cache=True, nogil=True)
def _largest_scale(dist, lever0, lengths, appr_cur, appr_nom, v_cur, a_cur, v_nom, a_max, j_max, v_h_meas, prm):
    """Largest s in [0, 1] with dist >= S_p(s) (bisection, 1/4096); -1 if even s = 0 fails."""
    N = dist.shape[0]
    sp = np.empty(N)

    def ok(s):
        _s_p(s, lever0, lengths, appr_cur, appr_nom, v_cur, a_cur, v_nom, a_max, j_max, v_h_meas, prm, sp)
        for k in range(N):
            if not dist[k] >= sp[k]:  # (a NaN S_p, from a non-finite motion, is not kept)
                return False
        return True

    if ok(1.0):
        return 1.0
    if not ok(0.0):
        return -1.0
    lo, hi = 0.0, 1.0
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        if ok(mid):
            lo = mid
        else:
            hi = mid
    return lo


@njit(cache=True, nogil=True)
def _to_now(dist, sp, appr_cur, appr_nom, s, v_h_meas, prm, age):
    """Shift ``dist`` and ``sp`` (N,) by what the obstacle and the point may have closed over ``age`` s:
    ``(v_h + v_r,k) age``, ``v_h`` as :func:`_s_p` chose it (measured, or ISO 13855 near / far, read back from
    ``sp`` against ``near_limit``; where the far branch is clamped to exactly ``near_limit`` this takes the
    larger near speed, a larger shift: the reported separation stays a lower bound)."""
    v_near, v_far, near_limit, v_floor = prm[2], prm[3], prm[4], prm[5]
    for k in range(dist.shape[0]):
        if v_h_meas[k] >= 0.0:
            v_h = max(v_h_meas[k], v_floor)
        else:
            v_h = v_near if sp[k] <= near_limit else v_far
        shift = (v_h + max(appr_cur[k], s * appr_nom[k])) * age
        dist[k] -= shift
        sp[k] -= shift


@njit(cache=True, nogil=True)
def _update(jac, qd, qdd, qn, distances, dirs, rng, lengths, a_max, j_max, v_h, prm, stopped, hyst, dist, sp, age):
    """:meth:`SsmMonitor.update` in one kernel: fills ``dist`` (N,) and ``sp`` (N,) (both for now: shifted by
    :func:`_to_now` over the data's ``age``); returns (scale or -1, stopped, stop_ended, T_s, binding)."""
    N, _, n = jac.shape
    lever0 = np.empty((N, n))
    appr_cur = np.empty(N)
    appr_nom = np.empty(N)
    for k in range(N):
        d = distances[k]
        dist[k] = 0.0 if np.isnan(d) else min(d, rng)
        # the direction is known only for a finite distance and a finite, nonzero vector: +inf ("nothing within
        # range", taken as the range) may lie in any direction (check_inputs hands on 0 there)
        norm = np.sqrt(dirs[k, 0] ** 2 + dirs[k, 1] ** 2 + dirs[k, 2] ** 2)
        good = d != np.inf and np.isfinite(norm) and norm > 0.0
        dc, dn, nc, nn = 0.0, 0.0, 0.0, 0.0
        for i in range(3):
            vc, vn = 0.0, 0.0
            for j in range(n):
                vc += jac[k, i, j] * qd[j]
                vn += jac[k, i, j] * qn[j]
            nc += vc * vc
            nn += vn * vn
            if good:
                dc -= dirs[k, i] / norm * vc
                dn -= dirs[k, i] / norm * vn
        appr_cur[k] = max(dc, 0.0) if good else np.sqrt(nc)
        appr_nom[k] = max(dn, 0.0) if good else np.sqrt(nn)
        for j in range(n):
            lever0[k, j] = np.sqrt(jac[k, 0, j] ** 2 + jac[k, 1, j] ** 2 + jac[k, 2, j] ** 2)
    s = _largest_scale(dist, lever0, lengths, appr_cur, appr_nom, qd, qdd, qn, a_max, j_max, v_h, prm)
    unknown = False  # an unknown (non-finite) motion: its S_p is unknown, stop (and no release)
    for j in range(n):
        if not (np.isfinite(qd[j]) and np.isfinite(qdd[j]) and np.isfinite(qn[j])):
            unknown = True
    for k in range(N):
        for j in range(n):
            if not np.isfinite(lever0[k, j]):
                unknown = True
    if unknown:
        s = -1.0
    ended = False
    if stopped:
        _s_p(0.0, lever0, lengths, appr_cur, appr_nom, qd, qdd, qn, a_max, j_max, v_h, prm, sp)
        release = not unknown
        for k in range(N):
            if not dist[k] >= sp[k] + hyst:
                release = False
        if release:
            stopped, ended = False, True
        else:
            s = -1.0
    if s < 0.0:
        stopped = True
    s_used = max(s, 0.0)
    T_s = _s_p(s_used, lever0, lengths, appr_cur, appr_nom, qd, qdd, qn, a_max, j_max, v_h, prm, sp)
    _to_now(dist, sp, appr_cur, appr_nom, s_used, v_h, prm, age)
    binding, best = -1, np.inf
    for k in range(N):
        m = dist[k] - sp[k]
        if np.isfinite(m) and (binding < 0 or m < best):
            binding, best = k, m
    return s, stopped, ended, T_s, binding
