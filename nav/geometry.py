"""Range geometry and the network's own coordinate frame (seed 000, constraints (1)).

The frame: station 1 at the origin, station 2 on +X, station 3 in the XY plane, and the
sign of Z chosen so that a designated fourth station has ``z > 0``. The frame is a proper
rigid motion of the physical world (right-handed, no mirror); ``y3`` may come out negative.
"""

from __future__ import annotations

import numpy as np

SPEED_OF_LIGHT_M_S = 299_792_458.0


def ranges(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance over the last axis: ``|a - b|``; a, b broadcast to (..., 3) -> (...)."""
    d = np.asarray(a) - np.asarray(b)
    return np.sqrt(np.einsum("...i,...i->...", d, d))


def line_of_sight(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``|a - b|`` (...) and its gradient in ``a``, the unit vector ``(a - b)/|a - b|`` (..., 3), at once.

    The geometry of every pseudorange model of the tree, ``rho = |p(t) - s| + b(t)`` (seed 001 eqs.
    13, 15; seed 002 eq. 6): each filter composes it with its own kinematics (``p(t)`` from its state at
    the reception time) and clock columns."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    r = np.sqrt(np.einsum("...i,...i->...", d, d))
    return r, d / r[..., None]


def range_jacobian(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Gradient of ``|a - b|`` with respect to ``a``: the unit vector ``(a - b)/|a - b|``; (..., 3)."""
    return line_of_sight(a, b)[1]


def frame_free_mask(n_stations: int) -> np.ndarray:
    """Boolean mask (n, 3) of free coordinates: station 1 none, 2 only x, 3 x and y, others all."""
    m = np.ones((n_stations, 3), dtype=bool)
    m[0, :] = False
    if n_stations > 1:
        m[1, 1:] = False
    if n_stations > 2:
        m[2, 2] = False
    return m


def to_network_frame(pos_m: np.ndarray, z_ref: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rigid transform of physical positions into the network's own frame.

    Parameters
    ----------
    pos_m : (n, 3) physical positions (any right-handed frame), stations in id order (index 0 = station 1).
    z_ref : index of the station that fixes the sign of +Z (default 3, i.e. station 4).

    Returns
    -------
    pos_frame : (n, 3) positions in the network frame.
    R : (3, 3) rotation with ``pos_frame = (pos_m - t) @ R.T``.
    t : (3,) physical position of station 1.
    """
    pos_m = np.asarray(pos_m, dtype=float)
    if pos_m.shape[0] < 3:
        raise ValueError("the network frame needs at least 3 stations")
    t = pos_m[0].copy()
    ex = pos_m[1] - t
    ex = ex / np.linalg.norm(ex)
    v = pos_m[2] - t
    ey = v - ex * (v @ ex)
    ny = np.linalg.norm(ey)
    if ny < 1e-9:
        raise ValueError("stations 1, 2, 3 are collinear: the frame is undefined")
    ey = ey / ny
    ez = np.cross(ex, ey)
    R = np.stack([ex, ey, ez])
    out = (pos_m - t) @ R.T
    if pos_m.shape[0] > z_ref and out[z_ref, 2] < 0:
        # rotate by pi about X: proper rotation, keeps 1-2-3 constraints, flips z
        F = np.diag([1.0, -1.0, -1.0])
        R = F @ R
        out = (pos_m - t) @ R.T
    out[0] = 0.0
    out[1, 1:] = 0.0
    out[2, 2] = 0.0
    return out, R, t
