"""Cramer-Rao bounds for aircraft positioning (pure math, vectorized over leading axes).

* :func:`fisher_cycle` - Fisher information of position and velocity from one TDMA cycle while the
  aircraft moves uniformly (seed 003 eqs. 5-7), optionally with an unknown receiver clock offset.
* :func:`crlb_cycle` - its inverse (seed 003 eq. 1) with horizontal / vertical position bounds.
* :func:`pcrb_linear_gaussian` - posterior CRLB (Tichavsky, Muravchik & Nehorai 1998) for linear
  Gaussian dynamics ``x_{k+1} = F x_k + w``, ``w ~ N(0, Q)`` and measurements ``z = h(x) + v``,
  ``v ~ N(0, R)``, with the measurement information ``H^T R^-1 H`` evaluated along the true trajectory.
  In that case the Tichavsky recursion ``J_{k+1} = D22 - D21 (J_k + D11)^-1 D12`` equals the
  covariance form ``P^-_{k+1} = F P_k F^T + Q``, ``P_{k+1} = (P^-_{k+1}^-1 + H^T R^-1 H)^-1`` which
  is used here because it tolerates a singular ``Q`` (the CV model's noise is rank-deficient).
"""

from __future__ import annotations

import numpy as np

from .geometry import range_jacobian
from .kalman import chol_solve, symmetrize


def fisher_cycle(
    r0_m: np.ndarray, v_m_s: np.ndarray, stations_m: np.ndarray, t_rel_s: np.ndarray,
    sigma_m: float | np.ndarray, clock: bool = False, velocity: bool = True,
) -> np.ndarray:
    """Fisher information of ``[r0, v (, b)]`` from one TDMA cycle (seed 003 eq. 7).

    Measurement ``i`` (slot at ``t_rel_s[i]`` after the cycle start): ``|r0 + v t_i - p_i| (+ b) + xi``,
    ``xi ~ N(0, sigma_i^2)`` (range units: ``c * sigma_t``).

    Parameters
    ----------
    r0_m : (..., 3) positions at the cycle start. v_m_s : (3,) or (..., 3) velocity.
    stations_m : (N, 3). t_rel_s : (N,). sigma_m : scalar or (N,).
    clock : add an unknown receiver clock offset (pseudoranges); velocity : estimate v (else known).

    Returns
    -------
    J : (..., k, k) with ``k = 3 (+3 if velocity) (+1 if clock)``.
    """
    r0 = np.asarray(r0_m, dtype=float)
    t = np.asarray(t_rel_s, dtype=float)
    pos_i = r0[..., None, :] + np.asarray(v_m_s, dtype=float)[..., None, :] * t[:, None]  # (..., N, 3)
    u = range_jacobian(pos_i, stations_m)  # (..., N, 3)
    cols = [u]
    if velocity:
        cols.append(u * t[:, None])
    if clock:
        cols.append(np.ones(u.shape[:-1] + (1,)))
    g = np.concatenate(cols, axis=-1)  # (..., N, k)
    w = 1.0 / np.broadcast_to(np.asarray(sigma_m, dtype=float) ** 2, t.shape)
    return np.einsum("n,...ni,...nj->...ij", w, g, g)


def crlb_cycle(J: np.ndarray, cond_max: float = 1e14) -> dict[str, np.ndarray]:
    """Bounds from a Fisher matrix (..., k, k) whose first 3 parameters are the position.

    Returns ``cov`` (..., 3, 3) position bound, ``horiz_m`` sqrt(var x + var y), ``vert_m`` sqrt(var z)
    and ``total_m``; points whose Fisher matrix is singular (condition > ``cond_max``) get ``inf``.
    """
    k = J.shape[-1]
    scale = np.sqrt(np.einsum("...ii->...i", J))
    scale = np.where(scale > 0, scale, 1.0)
    Jn = J / scale[..., :, None] / scale[..., None, :]  # equilibrate before factorizing
    cond = np.linalg.cond(Jn)
    bad = ~np.isfinite(cond) | (cond > cond_max)
    Jn = np.where(bad[..., None, None], np.eye(k), Jn)
    inv = chol_solve(Jn, np.broadcast_to(np.eye(k), Jn.shape).copy()) / scale[..., :, None] / scale[..., None, :]
    cov = symmetrize(inv)[..., :3, :3]
    hv = cov[..., 0, 0] + cov[..., 1, 1]
    vv = cov[..., 2, 2]
    out = {
        "cov": np.where(bad[..., None, None], np.inf, cov),
        "horiz_m": np.where(bad, np.inf, np.sqrt(np.maximum(hv, 0.0))),
        "vert_m": np.where(bad, np.inf, np.sqrt(np.maximum(vv, 0.0))),
    }
    out["total_m"] = np.hypot(out["horiz_m"], out["vert_m"])
    return out


def pcrb_linear_gaussian(
    P0: np.ndarray, F: np.ndarray, Q: np.ndarray, H_seq: np.ndarray, R_seq: np.ndarray,
) -> np.ndarray:
    """Posterior CRLB sequence for the filters (Tichavsky recursion, covariance form).

    Parameters
    ----------
    P0 : (n, n) or (..., n, n) prior covariance of the initial state (the bound at k = 0 before any
        measurement).
    F, Q : (n, n) transition and process noise per step (a step precedes every measurement batch).
    H_seq : (T, ..., m, n) measurement Jacobians at the true states (``...``: independent
        trajectories bounded at once). R_seq : (T, ..., m, m) or anything broadcastable to it.

    Returns
    -------
    P : (T, ..., n, n) the bound after the measurement batch of each step.
    """
    T = H_seq.shape[0]
    R_seq = np.broadcast_to(R_seq, H_seq.shape[:-2] + R_seq.shape[-2:])
    # information contributed by each batch: H^T R^-1 H, all steps at once
    RiH = chol_solve(R_seq, H_seq)
    Jz = symmetrize(np.swapaxes(H_seq, -1, -2) @ RiH)
    n = H_seq.shape[-1]
    out = np.empty(Jz.shape)
    P = np.broadcast_to(np.asarray(P0, dtype=float), Jz.shape[1:])
    eye = np.eye(n)
    for k in range(T):
        Pp = symmetrize(F @ P @ F.T + Q)
        # P = (Pp^-1 + Jz)^-1 = Pp - Pp Jz (I + Pp Jz)^-1 ... use the stable form (I + Pp Jz)^-1 Pp
        P = symmetrize(np.linalg.solve(eye + Pp @ Jz[k], Pp))
        out[k] = P
    return out


def prior_before_first_step(P0: np.ndarray, F: np.ndarray, Q: np.ndarray) -> np.ndarray:
    """The covariance one step before ``t0`` that :func:`pcrb_linear_gaussian` predicts to ``P0``.

    A filter measures its first batch at ``t0`` without a preceding prediction; the recursion always
    predicts first, so it starts from ``F^-1 (P0 - Q) F^-T`` (or ``P0`` if ``P0 - Q`` is not positive
    definite).
    """
    if np.all(np.linalg.eigvalsh(P0 - Q) > 0):
        Finv = np.linalg.inv(F)
        return Finv @ (P0 - Q) @ Finv.T
    return np.asarray(P0, dtype=float)


def pcrb_step(P: np.ndarray, Jz: np.ndarray, F: np.ndarray | None = None, Q: np.ndarray | None = None) -> np.ndarray:
    """One step of the posterior CRLB in covariance form for a varying step length: predict
    ``P <- F P F^T + Q`` (skipped when ``F`` is None: no time passed), then add the measurement
    information ``Jz = H^T R^-1 H``: ``P <- (I + P Jz)^-1 P``, symmetrized. (n, n) -> (n, n)."""
    if F is not None:
        P = F @ P @ F.T + Q
    return symmetrize(np.linalg.solve(np.eye(P.shape[-1]) + P @ Jz, P))

def gauss_markov_block(n_bias: int, var_m2: np.ndarray | float, tau_s: float, dt_s: float,
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Transition and process noise of ``n_bias`` independent first-order Gauss-Markov biases.

    ``b_{k+1} = a b_k + w_k``, ``a = exp(-dt / tau)``, ``w ~ N(0, (1 - a^2) var)``: stationary with
    variance ``var_m2`` (scalar or (n_bias,)) and correlation ``exp(-|t| / tau)``. ``tau_s = inf``
    gives constant biases. Returns ``(A, Qb)``, both (n_bias, n_bias) diagonal.
    """
    a, q = gauss_markov_diag(n_bias, var_m2, tau_s, dt_s)
    return a * np.eye(n_bias), np.diag(q)


def gauss_markov_diag(n_bias: int, var_m2: np.ndarray | float, tau_s: float, dt_s: float
                      ) -> tuple[float, np.ndarray]:
    """The diagonals of :func:`gauss_markov_block`: ``a = exp(-dt / tau)`` and ``(1 - a^2) var`` (n_bias,)."""
    if not tau_s > 0:
        raise ValueError(f"Gauss-Markov correlation time must be > 0, got {tau_s}")
    a = float(np.exp(-dt_s / tau_s))
    v = np.asarray(var_m2, dtype=float)
    if v.shape != (n_bias,):
        v = np.broadcast_to(v, (n_bias,))
    return a, (1.0 - a * a) * v


def augment_biases(
    P0: np.ndarray, F: np.ndarray, Q: np.ndarray, H_seq: np.ndarray, D: np.ndarray,
    var_m2: np.ndarray | float, tau_s: float, dt_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Augment a linear-Gaussian model with slowly varying measurement biases (Gauss-Markov states).

    The biases ``beta`` (nb,) enter the measurements as ``z = h(x) + D beta + v`` (pseudoranges:
    ``D = I``, one residual clock error per station; range differences: ``D = G``, seed 001 eq. 18)
    and follow :func:`gauss_markov_block`, starting from their stationary distribution
    ``N(0, var)`` independent of ``x``. The posterior CRLB of the augmented state
    ``[x, beta]`` (:func:`pcrb_linear_gaussian` on the returned matrices) is the bound of a world whose
    measurement errors are time-correlated this way; its ``x`` block bounds any estimator of ``x``.

    Parameters
    ----------
    P0 : (n, n) or (..., n, n). F, Q : (n, n). H_seq : (T, ..., m, n). D : (m, nb).
    var_m2 : stationary bias variances, scalar or (nb,). tau_s : correlation time. dt_s : step.

    Returns
    -------
    P0a (..., n+nb, n+nb), Fa, Qa (n+nb, n+nb), Ha (T, ..., m, n+nb).
    """
    n = F.shape[-1]
    D = np.asarray(D, dtype=float)
    nb = D.shape[-1]
    A, Qb = gauss_markov_block(nb, var_m2, tau_s, dt_s)
    Fa = np.zeros((n + nb, n + nb))
    Fa[:n, :n], Fa[n:, n:] = F, A
    Qa = np.zeros_like(Fa)
    Qa[:n, :n], Qa[n:, n:] = Q, Qb
    P0 = np.asarray(P0, dtype=float)
    P0a = np.zeros(P0.shape[:-2] + (n + nb, n + nb))
    P0a[..., :n, :n] = P0
    P0a[..., n:, n:] = np.diag(np.broadcast_to(np.asarray(var_m2, dtype=float), (nb,)))
    Ha = np.concatenate([H_seq, np.broadcast_to(D, H_seq.shape[:-1] + (nb,))], axis=-1)
    return P0a, Fa, Qa, Ha
