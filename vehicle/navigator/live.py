"""The live vehicle navigator: seed 004's map filter fed one sample at a time (``larns vehicle``).

Navigator side only (no truth): :class:`VehicleNavigator` is built from an *init record* (the map:
the route's points in the local ENU at a geodetic origin, the network frame -> ENU tie, the IMU step,
the noise intensities and the priors) and consumes what a device has:

* IMU blocks ``imu_block(k0, gyro, accel, odo)``: gyro (n, 3) rad/s with the known offset ``m_d``
  still in it, specific force (n, 3) m/s^2, odometer (n,) m/s, sample ``k`` held over
  ``[k dt, (k + 1) dt)`` of the vehicle's own time ``tau`` (seconds since its start);
* station measurements ``measurement(tau, src, pos_n, cov_n, clock_var, rho, rate)``: the reception
  time, the broadcast's station position and covariance in the network frame, the broadcast clock
  variance (m^2), the pseudorange (m) and the carrier pseudorange rate (m/s).

The filter is :class:`vehicle.navigator.cdekf.MapFilter` with receiver clock states (13 states, one
run). Between measurements it integrates whole IMU steps (``advance_to``); a measurement integrates up
to its reception time exactly (a partial step with the held sample) and is applied there (pseudorange
+ Doppler, Joseph form). At every whole second of ``tau`` ``D`` is re-orthonormalized and an estimate
is emitted; an estimate is emitted after every measurement too.

Start (no truth): attitude = the map's track frame at the route's first node (body x along the first
leg, z up; a 1 arcmin prior), ``q`` = the first node (``sigma_q0_m``), ``V`` = the first odometer
sample (``sigma_v0_m_s``), clock offset acquired from the first pseudorange whose variance (noise +
broadcast position + broadcast clock) is below ``ACQUIRE_VAR_M2`` (``rho - |s - p|``, prior
``sigma_b0_m``; the ones before are skipped), drift 0 (``sigma_d0_m_s``). A pseudorange whose
innovation exceeds ``GATE_SIGMA`` sigma is refused (counted).

Determinism: the result depends only on the sequence of calls and their arguments, which is what the
vehicle's journal records (``larns/vehicle/<name>/init`` and ``.../input``) so that
``larns reestimate`` re-runs it bit for bit (:func:`replay`).
"""

from __future__ import annotations

from collections import Counter
from typing import Any, Iterable

import numpy as np

from nav.geometry import line_of_sight
from nav.orbits import enu_to_ecef, greenwich_from_ecef
from vehicle.navigator.cdekf import Intensities, MapFilter, xi_matrix
from vehicle.route import Route, straight_route

ALGO = "cdekf-map"
ARCMIN = np.pi / (180.0 * 60.0)

#: init record keys: the map and the navigator's settings (all plain numbers / lists, net/messages.py)
RECORD_KEYS = ("route_enu_m", "origin_deg", "speeds_m_s", "net_to_enu", "net_offset_m", "t0_s", "dt_s",
               "q_gyro", "q_accel", "q_odo", "q_b", "q_d", "k_odo", "gyro_offset_rad_s", "sigma_rho_m",
               "sigma_rate_m_s", "sigma_q0_m", "sigma_v0_m_s", "sigma_att0_arcmin", "sigma_b0_m", "sigma_d0_m_s")


class MapTie:
    """The map's tie of the network frame to the Greenwich frame: ``p_g = J p_n + c`` (``J`` orthogonal).

    ``enu = net_to_enu @ p_n + net_offset_m`` at the geodetic ``origin_deg`` (lat, lon, h)."""

    def __init__(self, origin_deg, net_to_enu, net_offset_m):
        self.origin = tuple(float(v) for v in origin_deg)
        self.A = np.asarray(net_to_enu, float)
        self.b = np.asarray(net_offset_m, float)
        self.c = self.to_greenwich(np.zeros(3))
        self.J = np.stack([self.to_greenwich(e) - self.c for e in np.eye(3)], axis=-1)

    def enu(self, p_n: np.ndarray) -> np.ndarray:
        return np.asarray(p_n, float) @ self.A.T + self.b

    def to_greenwich(self, p_n: np.ndarray) -> np.ndarray:
        """Network frame (..., 3) -> Greenwich (..., 3)."""
        return greenwich_from_ecef(enu_to_ecef(self.enu(p_n), *self.origin))

    def to_network(self, p_g: np.ndarray) -> np.ndarray:
        """Greenwich (..., 3) -> network frame (..., 3)."""
        return (np.asarray(p_g, float) - self.c) @ self.J

    def vec_to_network(self, v_g: np.ndarray) -> np.ndarray:
        return np.asarray(v_g, float) @ self.J

    def cov_to_network(self, P_g: np.ndarray) -> np.ndarray:
        return self.J.T @ P_g @ self.J

    def cov_to_greenwich(self, P_n: np.ndarray) -> np.ndarray:
        return self.J @ P_n @ self.J.T


def route_of(rec: dict) -> Route:
    """The mapped route of an init record (straight legs in ENU at the origin)."""
    return straight_route(rec["route_enu_m"], rec["origin_deg"], None, rec["speeds_m_s"], name="vehicle")


def track_frame(route: Route) -> np.ndarray:
    """Body -> Greenwich direction cosines (3, 3) at the route's first node: x along the leg, z up."""
    seg = route.segments[0]
    x, z = seg.u, seg.up
    return np.stack([x, np.cross(z, x), z], axis=-1)


class VehicleNavigator:
    """Sans-I/O navigator (module doc). Outputs are estimate dicts (:meth:`estimate`)."""

    #: the clock offset is acquired from the first pseudorange whose variance is below this (m^2)
    ACQUIRE_VAR_M2 = 25.0
    #: pseudoranges whose innovation exceeds this many sigma are refused (counted: ``stats["gated"]``)
    GATE_SIGMA = 5.0

    def __init__(self, rec: dict[str, Any]):
        missing = [k for k in RECORD_KEYS if k not in rec]
        if missing:
            raise ValueError(f"vehicle init record: missing {missing}")
        self.rec = rec
        self.route = route_of(rec)
        self.tie = MapTie(rec["origin_deg"], rec["net_to_enu"], rec["net_offset_m"])
        self.t0_s = float(rec["t0_s"])
        self.dt = float(rec["dt_s"])
        self.per_s = int(round(1.0 / self.dt))
        if self.dt <= 0 or abs(self.per_s * self.dt - 1.0) > 1e-9:
            raise ValueError(f"dt_s must divide one second, got {self.dt}")
        self.noise = Intensities(gyro=float(rec["q_gyro"]), accel=float(rec["q_accel"]), odometer=float(rec["q_odo"]),
                                 q_b=float(rec["q_b"]), q_d=float(rec["q_d"]))
        self.m_d = float(rec["gyro_offset_rad_s"])
        self.filt: MapFilter | None = None
        self.samples: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.k = 0  # index of the IMU sample held at self.t
        self.t = 0.0  # filter time, vehicle seconds
        self.n_updates = 0
        self.clock_acquired = False
        self.last_nis = float("nan")
        self.stats: Counter[str] = Counter()

    # ------------------------------------------------------------------ inputs
    def imu_block(self, k0: int, gyro, accel, odo) -> None:
        """Store IMU / odometer samples ``k0 .. k0 + n - 1``; the first block starts the filter."""
        g = np.asarray(gyro, float).reshape(-1, 3)
        a = np.asarray(accel, float).reshape(-1, 3)
        z = np.asarray(odo, float).reshape(-1)
        if not (g.shape[0] == a.shape[0] == z.shape[0]):
            raise ValueError("imu block: gyro, accel and odometer lengths differ")
        for i in range(z.size):
            self.samples[int(k0) + i] = (g[i:i + 1] - self.m_d, a[i:i + 1], z[i:i + 1])
        if self.filt is None and 0 in self.samples:
            self._start(float(self.samples[0][2][0]))

    def _start(self, z0: float) -> None:
        rec = self.rec
        D = track_frame(self.route)  # inertial = Greenwich at tau = 0
        x0 = np.zeros((1, 13))
        x0[0, :9] = D.T.reshape(9)
        x0[0, 9] = float(self.route.q_start(0))
        x0[0, 10] = z0 / float(rec["k_odo"])
        P0 = np.zeros((1, 13, 13))
        Xi = xi_matrix(x0[:, :9].reshape(1, 3, 3))
        P0[:, :9, :9] = (float(rec["sigma_att0_arcmin"]) * ARCMIN) ** 2 * Xi @ np.swapaxes(Xi, 1, 2)
        P0[0, 9, 9] = float(rec["sigma_q0_m"]) ** 2
        P0[0, 10, 10] = float(rec["sigma_v0_m_s"]) ** 2
        P0[0, 11, 11] = float(rec["sigma_b0_m"]) ** 2
        P0[0, 12, 12] = float(rec["sigma_d0_m_s"]) ** 2
        self.filt = MapFilter(self.route, x0, P0, np.zeros(1, int), self.noise, clock=True, odometer=True,
                              k_odo=float(rec["k_odo"]))

    # ------------------------------------------------------------------ integration
    def _integrate(self, tau: float, partial: bool, out: list[dict]) -> None:
        """Integrate up to ``tau`` (whole steps; with ``partial`` the last step is cut at ``tau``)."""
        f = self.filt
        while f is not None and self.t < tau and self.k in self.samples:
            g, a, z = self.samples[self.k]
            t_end = (self.k + 1) * self.dt
            if tau < t_end:
                if partial:
                    f.step(self.t, tau - self.t, g, a, z)
                    self.t = tau
                return
            f.step(self.t, t_end - self.t, g, a, z)
            self.t = t_end
            del self.samples[self.k]
            self.k += 1
            if self.k % self.per_s == 0:
                f.orthonormalize()
                out.append(self.estimate("second"))

    def advance_to(self, tau: float) -> list[dict]:
        """Integrate every stored IMU step that ends at or before ``tau`` (vehicle seconds)."""
        out: list[dict] = []
        self._integrate(tau, False, out)
        return out

    def accepts(self, tau: float) -> bool:
        """Whether a measurement received at ``tau`` can still be applied (not before the filter time)."""
        return self.filt is not None and tau >= self.t

    def measurement(self, tau: float, src: int, pos_n, cov_n, clock_var_m2: float, rho_m: float,
                    rate_m_s: float) -> list[dict]:
        """Integrate to ``tau`` and apply one station's pseudorange and pseudorange rate. An unusable
        input (vehicle/navigator/plausible.py) is counted (``implausible_<reason>``) and dropped."""
        out: list[dict] = []
        from .plausible import bounds_of, measurement_reason

        why = measurement_reason(pos_n, cov_n, clock_var_m2, rho_m, rate_m_s, bounds_of(self.rec))
        if why is not None:
            self.stats["implausible_" + why] += 1
            return out
        if not self.accepts(tau):
            return out
        self._integrate(tau, True, out)
        if self.t != tau:  # IMU samples missing up to tau: cannot apply it here
            return out
        f = self.filt
        s_g = self.tie.to_greenwich(np.asarray(pos_n, float))
        cov_g = self.tie.cov_to_greenwich(np.asarray(cov_n, float))
        p, _, Jp, _ = f.geometry(tau, f.x)
        r, u = line_of_sight(s_g, p[0])  # u: receiver -> station
        r = float(r)
        rec = self.rec
        var_rho = float(rec["sigma_rho_m"]) ** 2 + float(u @ cov_g @ u) + float(clock_var_m2)
        var_rate = float(rec["sigma_rate_m_s"]) ** 2
        if not self.clock_acquired:  # the receiver clock offset from a well-synchronized broadcast
            if var_rho > self.ACQUIRE_VAR_M2:
                self.stats["before_clock"] += 1
                return out
            f.x[0, f.ib] = float(rho_m) - r
            self.clock_acquired = True
        H = -u @ Jp[0]
        H[f.ib] = 1.0
        s2 = float(H @ f.P[0] @ H) + var_rho
        nu = float(rho_m) - r - float(f.x[0, f.ib])
        if nu * nu > self.GATE_SIGMA**2 * s2:  # an outlier (a broadcast with a bad clock or position)
            self.stats["gated"] += 1
            return out
        f.update(tau, s_g[None], np.zeros((1, 3)), np.array([[float(rho_m)]]), np.array([[float(rate_m_s)]]),
                 np.array([var_rho]), np.array([var_rate]), use_rate=True)
        self.last_nis = float(f.last_nis[0])
        self.n_updates += 1
        out.append(self.estimate("update", src))
        return out

    # ------------------------------------------------------------------ output
    def estimate(self, why: str = "update", src: int | None = None) -> dict[str, Any]:
        """Position / velocity (network frame) and covariances at the filter time; fleet time ``t_s``."""
        f = self.filt
        p_g, v_g, Jp, Jv = f.geometry(self.t, f.x)
        P = f.P[0]
        cov_p = _psd(self.tie.cov_to_network(Jp[0] @ P @ Jp[0].T))
        cov_v = _psd(self.tie.cov_to_network(Jv[0] @ P @ Jv[0].T))
        extra = {"along_m": float(f.x[0, 9]), "speed_m_s": float(f.x[0, 10]), "clock_m": float(f.x[0, 11]),
                 "drift_m_s": float(f.x[0, 12]), "leg": float(f.seg[0]), "t0_s": self.t0_s,
                 "updated": 1.0 if why == "update" else 0.0}
        if why == "update":
            extra["nis"] = self.last_nis
            extra["station"] = float(src if src is not None else 0)
        return {"t_s": self.t0_s + self.t, "pos_m": self.tie.to_network(p_g[0]).tolist(), "cov_m2": cov_p.tolist(),
                "vel_m_s": self.tie.vec_to_network(v_g[0]).tolist(), "vel_cov": cov_v.tolist(), "algo": ALGO,
                "n_updates": self.n_updates, "extra": extra}


def _psd(C: np.ndarray) -> np.ndarray:
    """Symmetrized, with the variances clipped at 0: the map makes the cross-track and vertical
    variances zero in exact arithmetic, a rounding error of -1e-17 m^2 in floating point."""
    C = 0.5 * (C + C.T)
    i = np.arange(C.shape[0])
    C[i, i] = np.maximum(C[i, i], 0.0)
    return C


def replay(rec: dict[str, Any], entries: Iterable[list]) -> list[dict]:
    """Re-run the navigator on a journal (``["imu", k0, gyro, accel, odo]`` and
    ``["m", tau, src, pos_n, cov_n, clock_var, rho, rate]`` entries in order); returns its estimates.

    At the end it integrates every IMU step it was given (the live process may have stopped earlier
    or later: compare estimates by sequence number)."""
    nav = VehicleNavigator(rec)
    out: list[dict] = []
    for e in entries:
        if e[0] == "imu":
            nav.imu_block(e[1], e[2], e[3], e[4])
        elif e[0] == "m":
            out += nav.measurement(*e[1:])
    if nav.samples:
        out += nav.advance_to((max(nav.samples) + 1) * nav.dt)
    return out
