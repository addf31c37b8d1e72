"""Tuning of the radio filters (:class:`Tuning`, shared by all trajectories of a batch)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import numpy as np

from .state import StateLayout

# correlation time of a station's residual sync error after the broadcast correction, s (measured with
# the station clock filter on the seed000 world, TCXO clocks: docs/sync.md)
CLOCK_BIAS_TAU_S = 6.0
# correlation time of a station's broadcast position error (its survey's error, which persists for
# minutes), s: carried as consider states by default (docs/aircraft.md, Known limits, "On by default";
# 300 s or 3600 s re-fly the same recordings within a few per cent of NEES)
SURVEY_BIAS_TAU_S = 300.0


# The linearization rules of the radio filters, each switched off by leaving it out of
# ``Tuning.rules`` (``larns bench aircraft --without RULE``; which cells of the envelope each one holds:
# docs/aircraft.md, "Which cells each rule holds"). With none of them the filters are the textbook
# EKF / UKF. The constants each rule uses are stated here, not tuned per scenario.
RULES = ("inverse", "iterate", "lag", "repeats", "second-order", "weakest")

ITERATIONS = 2  # "iterate": update passes (one more re-linearization about the latest posterior) ...
ITERATE_THRESHOLD = 1.0  # ... for runs whose linearization error over the prior is large: tr(R^-1 Omega) > this
LINEARIZATION_CORR_S = 10.0  # "repeats": the second-order covariance counted as repeating over at most this
INVERSE_MAX_REL = 0.15  # "inverse": per run while sqrt(tr P_pos) < this x |p - c| (back above twice it) ...
INVERSE_MIN_RADII = 3.0  # ... and beyond this many array radii from the reference point
JACOBIAN_LAG_S = 2.0  # "lag": the Jacobian along one direction at the position low-passed over this
TRUNC_SIGMA = 6.0  # the height floor: truncate while the mean is < this many sigma above the floor
UKF_ALPHA = 0.1  # scaled sigma points (beta = 2, kappa = 0; seed 001)
CLOCK_BIAS_DROP_S = 60.0  # a station's clock-bias state is dropped after this long unheard


@dataclass(frozen=True)
class Prior:
    """Initial standard deviations of the filter state (diagonal): position (m, each axis), velocity
    (m/s), receiver clock offset (m) and rate (m/s)."""

    pos_m: float = 20.0
    vel_m_s: float = 5.0
    clock_m: float = 20.0
    drift_m_s: float = 1.0


@dataclass(frozen=True)
class Tuning:
    """One filter tuning (shared by all trajectories); nine knobs.

    ``q_acc`` white-acceleration density (m^2/s^3, every axis); ``q_clock`` receiver clock offset random
    walk (m^2/s); ``q_drift`` its rate random walk (m^2/s^3); ``sigma_m`` nominal pseudorange noise (m);
    ``p0`` the initial standard deviations (:class:`Prior`; a dict in TOML and in records);
    ``floor_z_m`` the station plane (LSQ mirrors below it, the filters truncate their density to above
    it; None: no floor); ``clock_bias_tau_s`` the correlation time of the stations' residual clock
    errors after the broadcast correction (docs/sync.md): each station heard gets a first-order
    Gauss-Markov range-bias state of stationary variance ``c^2 P_theta`` (its broadcast clock variance),
    0 = that variance added to each range as white noise instead (wrong for a slowly varying sync
    error: 4-8 x the bound, docs/sync.md); ``survey_bias_tau_s`` the correlation time of the stations'
    broadcast position errors, carried as consider range-bias states of stationary variance
    ``u^T C_j u`` (:mod:`.biases`; only with ``clock_bias_tau_s > 0`` and station covariances given),
    0 = ``u^T C_j u`` added to each range as white noise instead (overconfident where the errors persist);
    ``rules`` the linearization rules on
    (:data:`RULES`).

    The settings the rules imply are read-only properties below (``iterations``, ``coords``, ...).
    """

    q_acc: float = 1.0
    q_clock: float = 1e-4
    q_drift: float = 1e-4
    sigma_m: float = 0.5
    p0: Prior = field(default_factory=Prior)
    floor_z_m: float | None = 0.0
    clock_bias_tau_s: float = CLOCK_BIAS_TAU_S
    survey_bias_tau_s: float = SURVEY_BIAS_TAU_S
    rules: tuple[str, ...] = RULES

    def __post_init__(self):
        if isinstance(self.p0, dict):
            bad = set(self.p0) - {f.name for f in fields(Prior)}
            if bad:
                raise ValueError(f"p0: unknown keys {sorted(bad)}: expected some of pos_m, vel_m_s, clock_m, drift_m_s")
            object.__setattr__(self, "p0", Prior(**{k: float(v) for k, v in self.p0.items()}))
        rules = tuple(sorted(set(self.rules)))
        unknown = set(rules) - set(RULES)
        if unknown:
            raise ValueError(f"unknown rules {sorted(unknown)}: expected some of {list(RULES)}")
        object.__setattr__(self, "rules", rules)

    def without(self, *rules: str) -> "Tuning":
        """This tuning with the named rules switched off."""
        return replace(self, rules=tuple(r for r in self.rules if r not in rules))

    # -- what the rules imply
    @property
    def iterations(self) -> int:
        """Measurement-update passes: 1 = plain EKF / UKF; 2 re-linearizes once more about the latest
        posterior (EKF: Gauss-Newton IEKF; UKF: iterated posterior linearization)."""
        return ITERATIONS if "iterate" in self.rules else 1

    @property
    def iterate_threshold(self) -> float:
        """Iterate only runs whose linearization error over the prior is large: ``tr(R^-1 Omega) >`` this,
        ``Omega`` the statistical-linearization error covariance of h over the prior (UKF:
        ``Py - Pxz^T P^-1 Pxz``; EKF: its second-order term ``0.5 tr(M_i P M_j P)``)."""
        return ITERATE_THRESHOLD

    @property
    def ekf_second_order(self) -> bool:
        """EKF: Gaussian second-order terms of the range (Hessian ``(I - u u^T) / r``): mean correction
        ``0.5 tr(M_j P)`` and innovation covariance ``0.5 tr(M_i P M_j P)``."""
        return "second-order" in self.rules

    @property
    def linearization_corr_s(self) -> float:
        """The second-order covariance is a function of the state error, which changes slowly, so the
        same linearization error repeats at every update: it enters R scaled by the number of times it
        repeats, over at most this long (navigator/radio/repeats.py; 0 = white); the UKF gets the same
        term."""
        return LINEARIZATION_CORR_S if "repeats" in self.rules else 0.0

    @property
    def coords(self) -> str:
        """Filter coordinates: "inverse" (per run far out: the position inverted through the unit sphere
        about the broadcast station centroid, the clock carried as b + range to it:
        navigator/radio/coords.py) or "cartesian" ``[p, v, b, bdot]``."""
        return "inverse" if "inverse" in self.rules else "cartesian"

    @property
    def inverse_max_rel(self) -> float:
        return INVERSE_MAX_REL

    @property
    def inverse_min_radii(self) -> float:
        return INVERSE_MIN_RADII

    @property
    def height_jacobian_lag_s(self) -> float:
        """Runs in Cartesian coordinates: the Jacobian (EKF) or the sigma points' regression slope (UKF)
        along one direction taken at the position low-passed over this many seconds (restarted at the
        estimate beyond 4 sigma); 0 = at the estimate (docs/aircraft.md)."""
        return JACOBIAN_LAG_S if "lag" in self.rules else 0.0

    @property
    def lag_direction(self) -> str:
        """Which direction is lagged: "weakest" (the least observable position direction from the
        filter's own information, low-passed) or "height" (the height column)."""
        return "weakest" if "weakest" in self.rules else "height"

    @property
    def trunc_sigma(self) -> float:
        return TRUNC_SIGMA

    @property
    def alpha(self) -> float:
        return UKF_ALPHA

    @property
    def clock_bias(self) -> str:
        """"states" (a Gauss-Markov bias state per station) or "white" (``clock_bias_tau_s`` = 0)."""
        return "states" if self.clock_bias_tau_s > 0 else "white"

    @property
    def clock_bias_drop_s(self) -> float:
        return CLOCK_BIAS_DROP_S

    def prior_cov(self, layout: StateLayout) -> np.ndarray:
        """The initial covariance (n, n) of ``layout``'s states from :attr:`p0`."""
        p = self.p0
        d = [p.pos_m] * 3 + [p.vel_m_s] * 3
        if layout.kind == "pr":
            d.append(p.clock_m)
            if layout.drift:
                d.append(p.drift_m_s)
        return np.diag(np.square(d))
