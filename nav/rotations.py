"""Rotations (pure math, vectorized over leading axes).

Conventions: a direction cosine matrix ``C_ab`` maps frame-b coordinates to frame a:
``v_a = C_ab v_b``. Rotation vectors ``phi`` (..., 3) in radians; ``[w x]`` is the skew matrix with
``[w x] u = w x u``. Euler angles are the aerospace z-y-x sequence (yaw, pitch, roll):
``C_nb = Rz(yaw) Ry(pitch) Rx(roll)``.
"""

from __future__ import annotations

import numpy as np


_SKEW_BASIS = np.zeros((3, 9))
_SKEW_BASIS[0, [7, 5]] = 1.0, -1.0  # K[2,1] = w0, K[1,2] = -w0
_SKEW_BASIS[1, [2, 6]] = 1.0, -1.0  # K[0,2] = w1, K[2,0] = -w1
_SKEW_BASIS[2, [3, 1]] = 1.0, -1.0  # K[1,0] = w2, K[0,1] = -w2


def skew(w: np.ndarray) -> np.ndarray:
    """Skew matrices (..., 3, 3) of vectors (..., 3)."""
    w = np.asarray(w, dtype=float)
    return (w @ _SKEW_BASIS).reshape(w.shape[:-1] + (3, 3))


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rodrigues: rotation matrices (..., 3, 3) of rotation vectors (..., 3).

    ``exp([phi x]) = I + a [phi x] + b [phi x]^2`` with ``a = sin t / t`` and
    ``b = (1 - cos t) / t^2 = (sin(t/2) / (t/2))^2 / 2``, ``t = |phi|`` (no cancellation for small
    angles; ``t`` floored at 1e-300, where both ratios are exactly their limits 1 and 1/2).
    """
    phi = np.asarray(phi, dtype=float)
    t = np.maximum(np.sqrt(np.einsum("...i,...i->...", phi, phi)), 1e-300)
    a = np.sin(t) / t
    h = 0.5 * t
    b = 0.5 * (np.sin(h) / h) ** 2
    K = skew(phi)
    return np.eye(3) + a[..., None, None] * K + b[..., None, None] * (K @ K)


def log_so3(C: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of rotation matrices (..., 3, 3) (angles below pi)."""
    C = np.asarray(C, dtype=float)
    tr = np.clip((np.einsum("...ii->...", C) - 1.0) / 2.0, -1.0, 1.0)
    t = np.arccos(tr)
    v = np.stack([C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0], C[..., 1, 0] - C[..., 0, 1]], axis=-1)
    small = t < 1e-4
    s = np.where(small, 1.0, np.sin(np.where(small, 1.0, t)))
    f = np.where(small, 0.5 + t * t / 12.0, t / (2.0 * s))
    return f[..., None] * v


def dcm_from_euler(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """``C_nb = Rz(yaw) Ry(pitch) Rx(roll)`` (..., 3, 3)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    C = np.empty(np.broadcast(roll, pitch, yaw).shape + (3, 3))
    C[..., 0, 0] = cy * cp
    C[..., 0, 1] = cy * sp * sr - sy * cr
    C[..., 0, 2] = cy * sp * cr + sy * sr
    C[..., 1, 0] = sy * cp
    C[..., 1, 1] = sy * sp * sr + cy * cr
    C[..., 1, 2] = sy * sp * cr - cy * sr
    C[..., 2, 0] = -sp
    C[..., 2, 1] = cp * sr
    C[..., 2, 2] = cp * cr
    return C


def euler_from_dcm(C: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) (..., 3) of ``C_nb`` (inverse of :func:`dcm_from_euler`, |pitch| < pi/2)."""
    roll = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    pitch = -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(C[..., 1, 0], C[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def orthonormalize(C: np.ndarray) -> np.ndarray:
    """Nearest rotation (first-order correction ``C (3 I - C^T C) / 2``), (..., 3, 3)."""
    return 0.5 * C @ (3.0 * np.eye(3) - np.swapaxes(C, -1, -2) @ C)
