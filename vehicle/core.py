"""Sans-I/O vehicle for the live process (``larns vehicle``): world side + navigator + journal.

World (truth, inside the process, never handed to the navigator): the vehicle drives the mapped
route (:mod:`vehicle.world.truth`: speed plan, attitude along the track, analytic angular rate and
specific force) from its start at fleet time ``t0_s``; its IMU and odometer
(:mod:`vehicle.world.sensors`, seed 004's white noises, per-sample reading at the process's IMU step)
draw one block per second of vehicle time from the generator ``[seed, net.streams.VEHICLE, name, 1, block]``;
its receiver clock is seed 001's (``c dtau = df lambda t + c tau0``, the scenario's ``[vehicle]`` or
``[aircraft]`` ``df_hz``, ``lambda_m``, ``tau0_s``) on network time (station 1's oscillator), as the
aircraft's.

Radio: every station nav broadcast received in the vehicle's time (``larns/station/*/nav`` with its
``phy``): reception at ``t_rx = t_tx + |p(t_rx) - s| / c`` (the sender's true network-frame position
``phy.pos_m`` tied to the Earth by the map, true transmit time ``phy.t_true_s``), pseudorange
``rho = |p - s| + c (network time error - stamp error + broadcast correction) + b(t_rx) + n`` exactly
as the aircraft forms it (:func:`broadcast_time_error_s`), and the carrier pseudorange rate
``-u^T v + b'(t) + n'`` (docs/vehicle.md "Doppler from LARNS stations"), the noises drawn from the
generator of (station, broadcast seq). A station outage (``outage_s``, vehicle seconds) drops the
broadcasts received inside it (counted).

Navigator: :class:`vehicle.navigator.live.VehicleNavigator` fed the IMU blocks and the measurements.
Journal: everything the navigator consumed, in order: the ``veh_init`` (its init record; the same
record again after every :data:`INIT_EVERY_INPUTS` ``veh_input`` messages, so that a recorder whose
link came up after the vehicle's first publish still gets it) and ``veh_input`` messages (``entries``: ``["imu", k0, gyro, accel, odo]``, ``["m", tau, src, pos_n,
cov_n, clock_var, rho, rate]``); :func:`vehicle.navigator.live.replay` re-runs it bit for bit.
Outputs: ``veh_estimate`` (after each measurement and each whole second) and, for each, the world's
``veh_truth`` at the same time (network frame).
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S
from net import streams
from net.clock import broadcast_clock_var_m2
from net.nettime import pseudorange_time_error_s
from net.radio import link_var_m2, reception_sigma_m
from vehicle.navigator.live import MapTie, VehicleNavigator, route_of
from vehicle.world import sensors

#: the init record is re-sent after this many journal inputs (as a station re-sends ``core_init``)
INIT_EVERY_INPUTS = 10
from vehicle.world import truth as world_truth

DEFAULT_ORIGIN = (47.23, 39.72, 0.0)



def vehicle_map(scn, route_file: str | Path | None = None, speed_m_s: float | None = None) -> dict[str, Any]:
    """The map: route points in ENU at the origin and the network frame -> ENU tie.

    ``route_file``: a straight route in the network frame (``kind = "straight"``, ``points_m``,
    ``origin_deg``, optional ``rot_frame_to_enu``, ``speeds_m_s``; docs/routes/field-straight.toml).
    Without it: the default level W -> E route through the middle of the field
    (:func:`vehicle.field.field_route`, 5 m/s)."""
    if route_file is not None:
        import tomllib

        path = Path(route_file)
        if path.suffix.lower() in (".geojson", ".json"):
            raise ValueError(f"{path}: the vehicle process navigates by the LARNS stations: its route must be "
                             "straight legs in the network frame (a TOML [route] with kind = \"straight\")")
        r = tomllib.loads(path.read_text()).get("route")
        if r is None:
            raise ValueError(f"{path}: no [route] table")
        if r.get("kind", "great_circle") != "straight":
            raise ValueError(f"{path}: route.kind must be \"straight\" (legs in the network frame) for the vehicle "
                             "process; great circles are for satellite navigation (larns bench vehicle)")
        for key in ("points_m", "origin_deg"):
            if key not in r:
                raise ValueError(f"{path}: route.{key} is required")
        A = np.asarray(r.get("rot_frame_to_enu", np.eye(3)), float)
        pts = np.asarray(r["points_m"], float)
        n_legs = pts.shape[0] - 1
        speeds = r.get("speeds_m_s", 5.0)
        speeds = [float(speeds)] * n_legs if np.isscalar(speeds) else [float(v) for v in speeds]
        if speed_m_s is not None:
            speeds = [float(speed_m_s)] * n_legs
        return {"route_enu_m": (pts @ A.T).tolist(), "origin_deg": [float(v) for v in r["origin_deg"]],
                "speeds_m_s": speeds, "net_to_enu": A.tolist(), "net_offset_m": [0.0, 0.0, 0.0]}
    from vehicle.field import field_layout, field_route

    _, phys, _, R, t = field_layout(scn)
    route, pts_net = field_route(phys, R, t, speed_m_s=5.0 if speed_m_s is None else float(speed_m_s))
    return {"route_enu_m": (pts_net @ R + t).tolist(), "origin_deg": list(DEFAULT_ORIGIN),
            "speeds_m_s": list(route.speeds_m_s), "net_to_enu": R.T.tolist(), "net_offset_m": np.asarray(t).tolist()}


class VehicleCore:
    """World + navigator + journal; ``advance_to(t)`` and ``on_nav(msg, phy)`` return messages to publish."""

    algo = "cdekf-map"
    MAX_AHEAD_S = 60.0  # a broadcast received this far (vehicle s) past the filter time is refused
    lag_s = 1.0  # the node integrates this far (wall seconds x speed) behind fleet time: later broadcasts are late

    def __init__(self, scn, name: str = "veh1", seed: int | None = None, t0_s: float = 0.0, net_clock=None,
                 route_file: str | Path | None = None, imu_rate_hz: float = 20.0, speed_m_s: float | None = None,
                 outage_s: tuple[float, float] | None = None, sigma_rho_m: float = 0.5, sigma_rate_m_s: float = 0.15):
        self.name = name
        self.seed = int(scn.seed if seed is None else seed)
        self._key = streams.key(self.seed, streams.VEHICLE, streams.name_key(name))
        self.t0_s = float(t0_s)
        self.net_clock = net_clock
        self.outage_s = outage_s
        v = dict(scn.raw.get("aircraft", {}) or {}, **(scn.raw.get("vehicle", {}) or {}))
        self.clock_drift_m_s = float(v.get("df_hz", 20.0)) * float(v.get("lambda_m", 0.03))
        self.clock_tau0_m = SPEED_OF_LIGHT_M_S * float(v.get("tau0_s", 0.0))
        dt = 1.0 / float(imu_rate_hz)
        if abs(round(imu_rate_hz) - imu_rate_hz) > 1e-9 or imu_rate_hz <= 0:
            raise ValueError(f"--imu-rate must be a whole number of Hz, got {imu_rate_hz}")
        self.dt = dt
        self.per_s = int(round(imu_rate_hz))
        self.imu = sensors.ImuSpec(convention="per_sample")
        self.odo = sensors.OdometerSpec(convention="per_sample")
        clk = sensors.ClockSpec()
        m = vehicle_map(scn, route_file, speed_m_s)
        rec = dict(m, t0_s=self.t0_s, dt_s=dt,
                   q_gyro=sensors.intensity(self.imu.gyro, "per_sample", dt),
                   q_accel=sensors.intensity(self.imu.accel, "per_sample", dt),
                   q_odo=sensors.intensity(self.odo.sigma, "per_sample", dt), q_b=clk.q_b, q_d=clk.q_d,
                   k_odo=self.odo.k, gyro_offset_rad_s=self.imu.gyro_offset_rad_s, sigma_rho_m=float(sigma_rho_m),
                   sigma_rate_m_s=float(sigma_rate_m_s), sigma_q0_m=10.0, sigma_v0_m_s=0.1, sigma_att0_arcmin=1.0,
                   sigma_b0_m=100.0, sigma_d0_m_s=1.0)
        self.record = rec
        # world: the same map (the map's own error is not modelled)
        self.route = route_of(rec)
        self.tie = MapTie(rec["origin_deg"], rec["net_to_enu"], rec["net_offset_m"])
        self.plan = world_truth.speed_plan(self.route, None, stop_at_end=True)
        self.sigma_rho_m, self.sigma_rate_m_s = float(sigma_rho_m), float(sigma_rate_m_s)
        self.radio = getattr(scn.channel, "radio", None)  # [radio] in the network frame (world side)
        # navigator
        self.nav = VehicleNavigator(rec)
        self.blocks = 0  # IMU blocks generated (one per vehicle second)
        self.journal: list[list] = []
        self.seq: Counter[str] = Counter()
        self.stats: Counter[str] = Counter()
        self._pending: list[dict] = [self._msg("veh_init", self.t0_s, record=rec)]
        self._gen_block()

    # ------------------------------------------------------------------ world
    def truth(self, tau: float) -> tuple[np.ndarray, np.ndarray]:
        """True position and velocity (Greenwich) at vehicle time ``tau``."""
        tr = world_truth.sample(self.route, self.plan, np.array([max(tau, 0.0)]))
        return tr.p_g[0], tr.v_g[0]

    def clock_m(self, t_s: float) -> float:
        return self.clock_drift_m_s * t_s + self.clock_tau0_m

    def _gen_block(self) -> None:
        """IMU + odometer samples of the next second (journal entry, then to the navigator)."""
        b = self.blocks
        k0 = b * self.per_s
        t_mid = (k0 + np.arange(self.per_s) + 0.5) * self.dt
        tm = world_truth.sample(self.route, self.plan, t_mid)
        rng = np.random.default_rng(self._key + [1, b])
        g, a = self.imu.sample(tm.w_ib_b, tm.f_b, 1, self.dt, rng)
        z = self.odo.sample(tm.speed, 1, self.dt, rng)
        entry = ["imu", k0, g[:, 0].tolist(), a[:, 0].tolist(), z[:, 0].tolist()]
        self._flush()
        self.journal.append(entry)
        self.nav.imu_block(*entry[1:])
        self.blocks += 1

    def _flush(self) -> None:
        if self.journal:
            self._pending.append(self._msg("veh_input", self.t0_s + self.nav.t, entries=self.journal))
            self.journal = []
            if self.seq["veh_input"] % INIT_EVERY_INPUTS == 0:
                self._pending.append(self._msg("veh_init", self.t0_s, record=self.record))

    def _ensure_blocks(self, tau: float) -> None:
        while self.blocks * 1.0 <= tau + self.dt:
            self._gen_block()

    def measure(self, msg: dict, phy: dict) -> tuple[float, float, float, float] | None:
        """(t_rx fleet, pseudorange, pseudorange rate, one-way timing sigma in m) of one broadcast at
        the vehicle; ``None`` where the scenario's ``[radio]`` has no link (a vehicle behind the
        horizon: :func:`net.radio.reception_sigma_m`, the aircraft's channel model)."""
        s_g = self.tie.to_greenwich(np.asarray(phy["pos_m"], float))
        t_tx = float(phy["t_true_s"])
        p, v = self.truth(t_tx - self.t0_s)
        t_rx = t_tx + float(np.linalg.norm(p - s_g)) / SPEED_OF_LIGHT_M_S
        # over the microseconds of flight the motion is straight at v (acceleration <= 0.5 m/s^2: < 1e-11 m)
        p = p + v * (t_rx - t_tx)
        t_rx = t_tx + float(np.linalg.norm(p - s_g)) / SPEED_OF_LIGHT_M_S
        sigma = reception_sigma_m(np.asarray(phy["pos_m"], float), self.tie.to_network(p), self.radio,
                                  self.sigma_rho_m)
        if sigma is None:
            return None
        d = s_g - p
        r = float(np.linalg.norm(d))
        rng = np.random.default_rng(self._key + [2, int(msg["src"]), int(msg.get("seq", 0))])
        n = rng.standard_normal(2)
        rho = r + SPEED_OF_LIGHT_M_S * pseudorange_time_error_s(msg, t_tx, t_rx, self.net_clock) \
            + self.clock_m(t_rx) + sigma * float(n[0])
        rate = -float(d @ v) / r + self.clock_drift_m_s + self.sigma_rate_m_s * float(n[1])
        return t_rx, rho, rate, sigma

    # ------------------------------------------------------------------ shell-facing
    def advance_to(self, t_s: float) -> list[dict]:
        """Integrate the navigator to fleet time ``t_s`` (whole IMU steps)."""
        tau = t_s - self.t0_s
        if tau <= 0:
            return self._take()
        self._ensure_blocks(tau)
        return self._wrap(self.nav.advance_to(tau))

    def on_nav(self, msg: dict, phy: dict) -> list[dict]:
        """One station nav broadcast -> journal entry + ``veh_estimate`` / ``veh_truth`` messages."""
        if msg.get("state") not in ("frame", "surveying"):
            self.stats["nav_unusable_state"] += 1
            return self._take()
        from .navigator import plausible  # issue 32: an implausible nav never reaches the channel or the filter

        if plausible.refuse(msg, self.t0_s + self.nav.t, self.record, self.stats):  # (its filter time: its clock)
            return self._take()
        pos_n = np.asarray(msg["pos_m"], float)
        cov_n = np.asarray(msg["cov_m2"], float)
        if not (np.all(np.isfinite(pos_n)) and np.all(np.isfinite(cov_n))):
            self.stats["nav_bad"] += 1
            return self._take()
        got = self.measure(msg, phy)
        if got is None:
            self.stats["no_link"] += 1  # [radio]: beyond the horizon or the link budget
            return self._take()
        t_rx, rho, rate, sigma = got
        tau = t_rx - self.t0_s
        if tau < 0:
            self.stats["nav_before_start"] += 1
            return self._take()
        if tau > self.nav.t + self.MAX_AHEAD_S:  # not from the present (a bad stamp): would stall the IMU
            self.stats["nav_future"] += 1
            return self._take()
        if self.outage_s is not None and self.outage_s[0] <= tau <= self.outage_s[1]:
            self.stats["nav_outage"] += 1
            return self._take()
        self._ensure_blocks(tau)
        if not self.nav.accepts(tau):
            self.stats["nav_late"] += 1
            return self._take()
        # white range variance beside the nominal sigma: the broadcast clock's and the link's timing
        # variance above sigma_rho_m (known to the receiver from its SNR)
        cvar = broadcast_clock_var_m2(msg) + link_var_m2(sigma, self.sigma_rho_m)
        entry = ["m", tau, int(msg["src"]), pos_n.tolist(), cov_n.tolist(), cvar, rho, rate]
        self.journal.append(entry)
        self.stats["measurements"] += 1
        return self._wrap(self.nav.measurement(*entry[1:]))

    def close(self) -> list[dict]:
        """The last journal entries (call at exit)."""
        self._flush()
        return self._take()

    def _take(self) -> list[dict]:
        out, self._pending = self._pending, []
        return out

    def _wrap(self, ests: list[dict]) -> list[dict]:
        for e in ests:  # the truth first: a viewer pairs an estimate with the latest truth
            p, v = self.truth(e["t_s"] - self.t0_s)
            self._pending.append(self._msg("veh_truth", e["t_s"], t_s=e["t_s"], pos_m=self.tie.to_network(p).tolist(),
                                           vel_m_s=self.tie.vec_to_network(v).tolist()))
            self._pending.append(estimate_msg(self.name, self.seq, e))
        return self._take()

    def _msg(self, kind: str, stamp_s: float, **fields: Any) -> dict:
        self.seq[kind] += 1
        return {"kind": kind, "src": self.name, "seq": self.seq[kind], "stamp_s": float(stamp_s), **fields}


def estimate_msg(name: str, seq: Counter, e: dict) -> dict:
    """A navigator estimate as a ``veh_estimate`` message (the live core and the re-estimation alike)."""
    seq["veh_estimate"] += 1
    return {"kind": "veh_estimate", "src": name, "seq": seq["veh_estimate"], "stamp_s": float(e["t_s"]), **e}
