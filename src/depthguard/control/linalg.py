"""Small dense linear algebra for the control cycle, without LAPACK or BLAS calls.

At the controller's sizes (a 3 x 7 task Jacobian, up to 6 x 9 in the tests) the call and the workspace of
``np.linalg.svd`` / ``solve`` and of numba's BLAS-backed ``@`` cost more than the arithmetic, at 1 kHz
(BENCHMARKS.md, "The control cycle in one compiled call"). Used by SNS (:mod:`depthguard.control.sns`) and
the damped least squares of :mod:`depthguard.control.endeffector`.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["_jacobi_svd", "_damped_pinv", "_mv", "_mtv", "_masked"]


@njit(cache=True, nogil=True)
def _jacobi_svd(A: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-sided (Hestenes) Jacobi SVD of ``A`` (m, n): ``(B, W, sigma)`` with ``A^T W = B``, ``W`` (m, m)
    orthogonal, the columns of ``B`` (n, m) mutually orthogonal and ``sigma`` (m,) their norms, so
    ``A = sum_i sigma_i w_i (b_i / sigma_i)^T`` (unsorted). Rotations orthogonalise the columns of ``A^T``
    pairwise until every pair's cosine is below 1e-15 (quadratic convergence: a few sweeps for the
    controller's 3 x 7). Singular values come out with high *relative* accuracy (Demmel & Veselic 1992),
    and no LAPACK call or workspace is needed: much cheaper than ``np.linalg.svd`` at these sizes."""
    m, n = A.shape
    B = np.empty((n, m))
    for i in range(m):
        for j in range(n):
            B[j, i] = A[i, j]
    W = np.zeros((m, m))
    for i in range(m):
        W[i, i] = 1.0
    for _ in range(60):
        rotated = False
        for p in range(m - 1):
            for r in range(p + 1, m):
                alpha, beta, gamma = 0.0, 0.0, 0.0
                for k in range(n):
                    bp, br = B[k, p], B[k, r]
                    alpha += bp * bp
                    beta += br * br
                    gamma += bp * br
                if gamma == 0.0 or abs(gamma) <= 1e-15 * np.sqrt(alpha * beta):
                    continue
                rotated = True
                zeta = (beta - alpha) / (2.0 * gamma)
                t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
                c = 1.0 / np.sqrt(1.0 + t * t)
                s = c * t
                for k in range(n):
                    bp, br = B[k, p], B[k, r]
                    B[k, p] = c * bp - s * br
                    B[k, r] = s * bp + c * br
                for k in range(m):
                    wp, wr = W[k, p], W[k, r]
                    W[k, p] = c * wp - s * wr
                    W[k, r] = s * wp + c * wr
        if not rotated:
            break
    sigma = np.empty(m)
    for i in range(m):
        acc = 0.0
        for k in range(n):
            acc += B[k, i] * B[k, i]
        sigma[i] = np.sqrt(acc)
    return B, W, sigma


@njit(cache=True, nogil=True)
def _damped_pinv(A: np.ndarray, damping: float, rcond: float) -> tuple[np.ndarray, int]:
    """Damped pseudo-inverse ``V diag(s / (s^2 + damping^2)) U^T`` of ``A`` (m, n) and its numerical rank
    (singular values above ``rcond`` times the largest and above 1e-12). From :func:`_jacobi_svd`:
    ``v_i s_i / (s_i^2 + d^2) u_i^T = b_i w_i^T / (s_i^2 + d^2)``."""
    m, n = A.shape
    B, W, s = _jacobi_svd(A)
    smax = 0.0
    for i in range(m):
        smax = max(smax, s[i])
    rank = 0
    P = np.zeros((n, m))
    for i in range(m):
        if s[i] > rcond * max(smax, 1e-300) and s[i] > 1e-12:
            rank += 1
            g = 1.0 / (s[i] * s[i] + damping * damping)
            for r in range(n):
                br = B[r, i] * g
                for c in range(m):
                    P[r, c] += br * W[c, i]
    return P, rank


@njit(cache=True, nogil=True)
def _mv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``A @ x`` for a small A (r, c) by plain loops (numba's ``@`` calls BLAS, whose call costs more than
    the arithmetic at these sizes)."""
    r, c = A.shape
    out = np.zeros(r)
    for i in range(r):
        acc = 0.0
        for j in range(c):
            acc += A[i, j] * x[j]
        out[i] = acc
    return out


@njit(cache=True, nogil=True)
def _mtv(A: np.ndarray, x: np.ndarray) -> np.ndarray:
    """``A.T @ x`` for a small A (r, c) by plain loops (as :func:`_mv`)."""
    r, c = A.shape
    out = np.zeros(c)
    for i in range(r):
        for j in range(c):
            out[j] += A[i, j] * x[i]
    return out


@njit(cache=True, nogil=True)
def _masked(J: np.ndarray, free: np.ndarray) -> np.ndarray:
    """``J`` (m, n) with the columns of the joints that are not ``free`` set to 0."""
    m, n = J.shape
    JW = np.zeros((m, n))
    for i in range(m):
        for j in range(n):
            if free[j]:
                JW[i, j] = J[i, j]
    return JW
