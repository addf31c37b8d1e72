"""The map filter's single-run RK4 step as one compiled kernel (:func:`rk4_fused`).

One 1000 s paper run is 100 000 RK4 steps of an 11-state filter: with NumPy each step is some 40
calls on 11 x 12 arrays and costs ~0.1 ms of interpreter and call overhead, not arithmetic. When
`numba <https://numba.pydata.org>`_ is installed (the ``bench`` extra) the kernel below is compiled
once per machine (~13 s, then cached on disk next to this file) and a step costs ~2.3 times less;
without it, or with ``LARNS_JIT=off``, the very same function runs as NumPy code. Both give the
batched reference path's numbers to round-off (tests/vehicle/test_vehicle_filter_fast.py); on the
paper case they were bit-identical.
"""

from __future__ import annotations

import math
import os

import numpy as np


def _jit_wanted() -> bool:
    """numba installed and ``LARNS_JIT`` not ``off`` (the default test suite sets it off: the first
    compilation on a machine takes ~13 s; ``tests/vehicle/test_vehicle_filter_fast.py`` compiles it)."""
    if os.environ.get("LARNS_JIT", "on").lower() in ("off", "0", "no", "false"):
        return False
    try:
        import numba  # noqa: F401
    except ImportError:  # the Docker image: no numba
        return False
    return True


COMPILED = _jit_wanted()
if COMPILED:
    from numba import njit as _njit
else:
    def _njit(*_a, **_k):
        return lambda f: f


@_njit(cache=True)
def speed_factor_one(q, gP, a0, a1):
    """Scalar :meth:`vehicle.route.Route.speed_factor_d` of a great-circle segment (constants
    ``gP, a0, a1``) at ``q``: ``(sf, d sf / d q)`` (the same operations)."""
    den = max(a1 - q * q, 1e-6 * a1)
    sf = math.sqrt(1.0 + gP * gP + a0 * a0 * q * q / den)
    return sf, a0 * a0 * a1 * q / (den * den * sf)


@_njit(cache=True)
def _stage(Zs, KK, FH, Qm, m, z, ks, sr, gP, a0, a1):
    """``KK = [F; H] Zs`` and the derivative of ``Z = [P | x]`` in ``KK[:n]`` (returned).

    ``F P + (F P)^T + Q`` in the covariance columns, ``F x`` in the last; with the odometer
    (``m = n + 1``) ``H`` is evaluated at the stage's ``(q, V)`` (scalar speed factor of the great
    circle, :meth:`vehicle.route.Route.speed_factor_d`) and ``- P H^T H P / r + P H^T nu / r`` added."""
    n = Zs.shape[0]
    odo = m > n
    V = 0.0
    sf = 0.0
    if odo:
        V = Zs[10, n]
        sf, dsf = speed_factor_one(Zs[9, n], gP, a0, a1)
        FH[n, 9] = ks * sr * V * dsf
        FH[n, 10] = ks * sr * sf
    KK[:m] = FH[:m] @ Zs
    K = KK[:n]
    FP = K[:, :n]
    FP += FP.T + Qm
    if odo:
        KK[n, n] = -(z - ks * V * sf) * sr
        K -= np.outer(KK[n, :n], KK[n])
    return K


@_njit(cache=True)
def rk4_fused(Z, KK, FH, Qm, m, dt, z, ks, sr, gP, a0, a1):
    """One RK4 step of ``Z = [P | x]`` (n, n + 1), in place; ``P`` symmetrized.

    ``KK`` (4, n + 1, n + 1): work space of the four stages. ``FH`` (n + 1, n): ``F`` with the step's inputs in its first n rows (held over the step), the
    odometer row filled per stage; ``Qm`` (n, n) the process noise; ``m`` = n + 1 with the odometer
    sample ``z`` (m/s), n without; ``ks = k_odo * sign``, ``sr = 1 / sqrt(r)``; ``gP, a0, a1`` the
    segment's great-circle constants. Spec Sec. 3.5 (eq. 6 of seed 004)."""
    n = Z.shape[0]
    h2 = 0.5 * dt
    k1 = _stage(Z, KK[0], FH, Qm, m, z, ks, sr, gP, a0, a1)
    k2 = _stage(Z + h2 * k1, KK[1], FH, Qm, m, z, ks, sr, gP, a0, a1)
    k3 = _stage(Z + h2 * k2, KK[2], FH, Qm, m, z, ks, sr, gP, a0, a1)
    k4 = _stage(Z + dt * k3, KK[3], FH, Qm, m, z, ks, sr, gP, a0, a1)
    Z += (k1 + 2.0 * (k2 + k3) + k4) * (dt / 6.0)
    Pn = Z[:, :n]
    Pn[:, :] = 0.5 * (Pn + Pn.T)


def warm_up() -> None:
    """Compile (or load from the cache) the kernel outside any timed loop."""
    n = 11
    Z = np.zeros((n, n + 1))
    rk4_fused(Z, np.zeros((4, n + 1, n + 1)), np.zeros((n + 1, n)), np.zeros((n, n)), n + 1, 0.01, 0.0, 1.0,
              1.0, 0.0, 1.0, 1.0)
    speed_factor_one(0.0, 0.0, 1.0, 1.0)
