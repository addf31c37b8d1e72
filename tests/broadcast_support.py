"""A station's nav broadcast as the user receivers' cores take it (tests of the aircraft and vehicle)."""

from __future__ import annotations

import numpy as np


def nav_broadcast(scn, sid: int, t_s: float, sigma_pos_m: float = 0.1) -> tuple[dict, dict]:
    """``(msg, phy)`` of station ``sid``'s nav sent at ``t_s`` from its true position (network frame),
    broadcast covariance ``sigma_pos_m^2 I``, station clock perfect."""
    msg = {"kind": "nav", "src": sid, "seq": int(t_s * 10), "stamp_s": t_s, "t_tx_s": t_s,
           "pos_m": scn.true_pos(sid).tolist(), "cov_m2": (np.eye(3) * sigma_pos_m**2).tolist(),
           "n_updates": 50, "state": "frame", "ranges": [], "members": list(scn.ids)}
    return msg, {"pos_m": scn.true_pos(sid).tolist(), "t_true_s": t_s}
