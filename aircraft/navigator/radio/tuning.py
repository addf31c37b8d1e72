"""Tuning of the radio filters (:class:`Tuning`, shared by all trajectories of a batch)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .state import StateLayout

# correlation time of a station's residual sync error after the broadcast correction, s (measured with
# the station clock filter on the seed000 world, TCXO clocks: docs/sync.md)
CLOCK_BIAS_TAU_S = 6.0


@dataclass(frozen=True)
class Tuning:
    """One filter tuning (shared by all trajectories).

    ``q_acc`` white-acceleration density (m^2/s^3), ``q_acc_z`` its vertical one; ``q_clock`` clock random walk (m^2/s);
    ``q_drift`` clock-rate random walk (m^2/s^3, drift state only); ``alpha`` UKF spread;
    ``sigma_m`` nominal pseudorange noise; ``p0_*`` initial standard deviations.
    """

    q_acc: float = 1.0
    q_acc_z: float | None = None  # vertical white-acceleration density; None = q_acc
    q_clock: float = 1e-4
    q_drift: float = 1e-4
    drift_state: bool = True
    alpha: float = 1e-1
    sigma_m: float = 0.5
    p0_pos_m: float = 20.0
    p0_vel_m_s: float = 5.0
    p0_clock_m: float = 20.0
    p0_drift_m_s: float = 1.0
    floor_z_m: float | None = 0.0  # station plane: LSQ mirrors below it, filters truncate (None: off)
    trunc_sigma: float = 6.0
    sequential: bool = False  # pseudorange epochs as sequential scalar updates (else one vector update)
    # iterated measurement update: 1 = plain EKF/UKF; k > 1 re-linearizes k - 1 more times about the
    # latest posterior (EKF: Gauss-Newton IEKF; UKF: iterated posterior linearization, the statistical
    # linear regression of h over the latest posterior's sigma points)
    iterations: int = 2
    # ... only for runs whose linearization error over the prior is large: tr(R^-1 Omega) > this, with
    # Omega the statistical-linearization error covariance of h over the prior (UKF: Py - Pxz^T P^-1 Pxz;
    # EKF: its second-order term 0.5 tr(M_i P M_j P), with R already including that term when
    # ekf_second_order is on). 0 = always iterate.
    iterate_threshold: float = 1.0
    # EKF: Gaussian second-order terms of the range (Hessian (I - u u^T) / r): mean correction
    # 0.5 tr(M_j P) and innovation covariance 0.5 tr(M_i P M_j P). Close to a transmitter the range's
    # curvature biases a first-order EKF (the UKF captures it through its sigma points).
    ekf_second_order: bool = True
    # ... and that term's covariance is not white: it is a function of the state error, which changes
    # slowly (the stations' clock biases, the hover), so the same linearization error repeats at every
    # update. It enters R scaled by the number of times it repeats: the longer of the filter's memory
    # time and the time since its start, at most this long, over the station's own measurement interval
    # (navigator/radio/repeats.py; 0 = white, the textbook second-order EKF); the UKF gets the same term.
    # Far from the transmitters it is negligible; 2.6 m above one (seed001 hover 50 m) it keeps the
    # filters from reading curvature as information (docs/aircraft.md, "Linearization error").
    linearization_corr_s: float = 10.0
    # filter coordinates: "inverse" = position inverted through the unit sphere about the broadcast
    # station centroid and the clock carried as b + range to it (aircraft/navigator/radio/coords.py: straightens the
    # height/clock and range/clock ridges of a small-base system); "cartesian" = [p, v, b, bdot]
    coords: str = "inverse"
    # ... per run, only while the position is known well relative to its distance from the reference:
    # sqrt(tr P_pos) < inverse_max_rel * |p - c| (back to Cartesian above twice that; near the
    # array the inversion of a wide Gaussian is itself far from Gaussian). Checked after every update.
    inverse_max_rel: float = 0.15
    # ... and only beyond this many array radii (RMS station distance from the centroid) from the
    # reference: close to the array the ranges to single stations dominate the nonlinearity
    inverse_min_radii: float = 3.0
    # runs in Cartesian coordinates (near the array): the Jacobian (EKF) or the sigma points'
    # regression slope (UKF) along one direction is taken at the position low-passed over this many
    # seconds (restarted at the estimate beyond 4 sigma: a moving aircraft). Where a direction is not
    # observable (right above the array: the height; on a mirror plane of the square: x, z and the
    # clock) the Jacobian along it, taken at the estimate, is proportional to the estimate's own error
    # across it, which the innovation also carries, and the noise-driven product drove the estimate
    # along the ridge (~2 m/s up at hover 100 m overhead, docs/aircraft.md). 0 = at the estimate.
    height_jacobian_lag_s: float = 2.0
    # ... which direction: "weakest" (the least observable position direction from the filter's own
    # information, low-passed; the position lagged across it, current along it) or "height" (the
    # height column at the low-passed horizontal position; docs/aircraft.md, "History of the rules")
    lag_direction: str = "weakest"
    # residual station clock errors after the broadcast clock correction (docs/sync.md): "states" = one
    # first-order Gauss-Markov range bias per station heard, stationary variance = the broadcast clock
    # variance c^2 P_theta, correlation time ``clock_bias_tau_s`` (added as a station is first heard,
    # dropped after ``clock_bias_drop_s`` without a measurement); "white" = the broadcast variance added
    # to each range's variance as if independent between measurements (wrong for a slowly varying
    # sync error: 4-8 x the bound, docs/sync.md)
    clock_bias: str = "states"
    clock_bias_tau_s: float = CLOCK_BIAS_TAU_S
    clock_bias_drop_s: float = 60.0

    def p0(self, layout: StateLayout) -> np.ndarray:
        d = [self.p0_pos_m] * 3 + [self.p0_vel_m_s] * 3
        if layout.kind == "pr":
            d.append(self.p0_clock_m)
            if layout.drift:
                d.append(self.p0_drift_m_s)
        return np.diag(np.square(d))
