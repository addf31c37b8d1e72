"""Sans-I/O triad aircraft for the live process (``--satellites N``, algorithm ``triad``, seed 002).

World (truth): :class:`aircraft.world.triad.TriadWorld`, its own object held as ``world`` - the
scenario's physical coordinates as the ENU frame :class:`nav.constellation.EnuFrame` at ``ORIGIN``
(the triad benchmark's), the 6-DOF motion of ``[aircraft.trajectory]``, the GPS-like sky (one model
with :mod:`aircraft.montecarlo.triad`: :mod:`aircraft.world.sky`), the scenario's receiver clock, the
IMU, the baro, the tie stations' geodetic survey and the station radio channel (as the INS core's).
Measurements: every whole second of the IMU grid, the pseudoranges of the ``N`` satellites highest
at the start that are above the mask and the baro altitude; every station nav broadcast, a
pseudorange.

Navigator side (no truth): :class:`aircraft.navigator.triad_ekf.TriadEkf` (24 states). Start: a
constant-velocity window fix over the first ``INIT_WINDOW_S`` from every satellite above the mask
(the full sky, as the benchmark: the degradation to ``N`` satellites starts after it) and a levelling
(:func:`aircraft.navigator.triad_ekf.initial_fix`, :func:`start_from_window`); broadcasts before it
are counted (``nav_before_start``) and give no estimate. Earth tie: from the latest broadcast network-frame
positions of the tie stations and their geodetic survey (:func:`aircraft.navigator.field_tie.tie`,
recomputed per broadcast); the tie's covariance along the line of sight is added to the range
variance (the white treatment). Broadcasts before the three tie stations have been heard are
counted (``nav_no_tie``) and give no estimate. Every broadcast received in time (its positions feed the
tie) is published as ``ac_truth``. Estimates and ``ac_truth`` are in the Earth-tied frame.

Journal (exact re-flight, ``larns reestimate``; aircraft/journal.py): the navigator's init record
holds what a receiver knows (satellites in view at the start, the tie stations' geodetic survey, the
IMU preset and rate, the baro model); the world hands it the IMU increments, each epoch's satellite
pseudoranges and baro height and each broadcast received in time, journaled in the order consumed;
:meth:`from_record` rebuilds the navigator without a world. The IMU blocks, each satellite epoch and
each station measurement draw from their own generators keyed by the world seed and the block, epoch
or (station, broadcast seq) (the world's doc).
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np

from nav.constellation import EnuFrame, gps_like
from nav.rotations import euler_from_dcm
from net import streams
from net.clock import broadcast_clock_var_m2
from net.radio import link_var_m2

from .core import InertialCore
from .ins_core import motion_from_config
from .journal import AcJournal
from .navigator import field_tie as ft
from .navigator import receiver as rx
from .navigator.ins_ekf import InsTuning
from .navigator.triad_ekf import Epoch, TriadEkf, initial_fix, start_from_window, turn_corrected
from .radio_core import radio_record
from .world import baro as wbaro
from .world import clock as wclock
from .world.imu import PRESETS, preset
from .world.triad import TriadWorld

ORIGIN = (55.75, 37.62, 0.0)  # geodetic origin of the physical frame (deg, deg, m): the triad bench's
DEFAULT_IMU = "navigation"


class TriadAircraftCore(InertialCore):
    """Pure apart from its seeded generators: ``advance_to(t)`` and ``on_nav(msg, phy)`` (module doc); the
    node's side (``lag_s``, ``tick``, ``status_line``, ``summary``) in :class:`aircraft.core.InertialCore`."""

    algo = "triad"
    BLOCK = 100
    INIT_WINDOW_S = 10.0
    EPOCH_S = 1.0
    START_ATT_SIGMA_RAD = np.radians(2.0)  # added to the start's attitude prior (turning flight)

    def __init__(self, sc, ac, name: str, n_sv: int = 4, imu: str | None = None, imu_rate_hz: float = 10.0,
                 height_m: float | None = None, seed: int | None = None, t0_s: float = 0.0, net_clock=None,
                 sigma_sat_m: float = 3.0, mask_deg: float = 10.0, baro: wbaro.BaroModel | None = None,
                 sigma_tie_m: tuple = (0.05, 0.05, 0.1)):
        if n_sv < 0:
            raise ValueError("--satellites must be >= 0")
        self.ac = ac  # aircraft.config.AircraftConfig: the world reads ac.world, the navigator gets ac.nav
        seed = int(sc.seed if seed is None else seed)
        pre = preset(imu or DEFAULT_IMU).with_(rate_hz=float(imu_rate_hz))
        motion = motion_from_config(ac.world.trajectory, height_m if height_m is not None else ac.world.height_m)
        key = streams.key(seed, streams.AIRCRAFT_TRIAD, streams.name_key(name))
        self.world = TriadWorld(sc, ac.world, key, EnuFrame(*ORIGIN), motion, pre, self.BLOCK, t0_s, self.EPOCH_S,
                                net_clock, sigma_sat_m, mask_deg, baro or wbaro.BaroModel(), sigma_tie_m)
        visible = self.world.visible  # the full sky of the start window, highest first
        if int(n_sv) > visible.size:
            raise ValueError(f"--satellites {n_sv}: only {visible.size} above the mask at the start")
        station_ids = [int(s["id"]) for s in sorted(sc.raw["stations"], key=lambda s: int(s["id"]))]
        # --- navigator: what a receiver knows (its init record, aircraft/journal.py) ---------------
        self.bounds = ac.nav.field_bounds  # the deployment plan's plausibility bounds
        b = self.world.baro_model
        record = dict(radio_record(ac.nav, ()), kind="triad", n_sv=int(n_sv), imu=imu or DEFAULT_IMU,
                      imu_rate_hz=float(imu_rate_hz), sigma_range_m=float(ac.nav.sigma_range_m), t0_s=float(t0_s),
                      sigma_sat_m=float(sigma_sat_m), mask_deg=float(mask_deg),
                      baro=[float(b.sigma_m), float(b.sigma_bias_m), float(b.tc_s)],
                      visible=[int(i) for i in visible], tie_ids=station_ids[:3],
                      sigma_tie_m=[float(x) for x in sigma_tie_m],
                      tie_surveyed_m=self.world.tie_surveyed_m.tolist())
        self._inputs = None  # the replay's samples and epochs (from_record); None: the world above
        self.journal = AcJournal(name, record)
        self._navigator(record, name)

    def _navigator(self, record: dict, name: str) -> None:
        self.name = name
        self.n_sv = int(record["n_sv"])
        self.t0_s = float(record["t0_s"])
        self.frame = EnuFrame(*ORIGIN)  # the receiver's: the field's geodetic origin and the almanac
        self.alm = gps_like()
        self.imu_name = record["imu"]
        self.preset = preset(self.imu_name).with_(rate_hz=float(record["imu_rate_hz"]))
        self.sigma_sat_m, self.mask_deg = float(record["sigma_sat_m"]), float(record["mask_deg"])
        sb, sbb, tcb = record["baro"]
        cm = wclock.ClockModel()
        self.tn = InsTuning.from_preset(self.preset, sigma_range_m=record["sigma_range_m"], q_b=cm.q_b_m2_s,
                                        q_d=cm.q_d_m2_s3, sigma_baro_m=sb, sigma_baro_bias_m=sbb, tc_baro_s=tcb,
                                        max_prop_s=1.0)
        self.spe = int(round(self.EPOCH_S * self.preset.rate_hz))
        self.n_init = int(round(self.INIT_WINDOW_S * self.preset.rate_hz))
        self.visible = np.asarray(record["visible"], dtype=int)
        self.sat_ids = self.visible[: self.n_sv]
        self.tie_ids = [int(i) for i in record["tie_ids"]]
        self.sigma_tie_m = np.asarray(record["sigma_tie_m"], float)
        self.tie_surveyed_m = np.asarray(record["tie_surveyed_m"], float)
        self.ekf: TriadEkf | None = None
        self._window: list[np.ndarray] = []  # (N_vis,) pseudoranges per start epoch
        self._window_t: list[float] = []
        self._f_sum = np.zeros(3)
        self._w_sum = np.zeros(3)
        self._broadcast: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # src -> network pos, cov
        self.imu_steps = 0
        self.seq: Counter[str] = Counter()
        self.stats: Counter[str] = Counter()
        self._pacer = rx.StatusPacer()
        self._epoch(0)

    @classmethod
    def from_record(cls, record: dict, name: str, inputs) -> "TriadAircraftCore":
        """The navigator alone, fed the IMU samples and epochs of a journal (:class:`aircraft.journal.Inputs`)."""
        core = cls.__new__(cls)
        core._inputs = inputs
        core.journal, core.world = None, None
        core._navigator(record, name)
        return core

    def truth_n(self, t_s: float):
        """The world's truth (position, velocity, attitude) at ``t_s``, for the status line and summary."""
        return self.world.truth_n(t_s)

    # ---------------------------------------------------------------------------- navigator
    def _epoch(self, k: int) -> None:
        """Epoch ``k`` (the IMU step ending at ``t0 + k``): window data before the start, then the
        filter's satellite + baro update."""
        t = self.t0_s + k * self.EPOCH_S
        if self.ekf is None:
            self._window.append(self._epoch_data(k, self.visible, False)[0])
            self._window_t.append(t)
            if k * self.spe >= self.n_init:
                self._start()
            return
        z, baro = self._epoch_data(k, self.sat_ids, True)
        ok = np.isfinite(z)
        s = self.ekf.epoch(Epoch(self.ekf.t_s, self.sat_ids[ok], z[None, ok], baro_m=np.array([baro])))
        self.stats["sat_used"] += s["sat_used"]
        self.stats["sat_masked"] += s["sat_masked"] + int(np.sum(~ok))

    def _epoch_data(self, k: int, ids: np.ndarray, with_baro: bool) -> tuple[np.ndarray, float | None]:
        """Epoch ``k``'s satellite pseudoranges of ``ids`` (NaN below the mask) and, after the start,
        the baro height: from the world (journaled) or, in a replay, from the journal."""
        if self._inputs is not None:
            return self._inputs.epoch(k)
        z = self.world.sky(k, ids)
        baro = self.world.baro(k) if with_baro else None
        self.journal.sv(k, self.t0_s + k * self.EPOCH_S, z, baro)
        return z, baro

    def _start(self) -> None:
        rho = np.stack(self._window)[None]  # (1, K, N_vis)
        t_ref = self._window_t[-1]
        x, cov, cost = initial_fix(self.alm, self.frame, np.asarray(self._window_t), self.visible, rho,
                                   self.sigma_sat_m, t_ref)
        f_mean = self._f_sum / self.INIT_WINDOW_S
        st = start_from_window(self.tn, x, cov, f_mean[None], cost, 0)
        st = turn_corrected(st, float(self._w_sum[2]) / self.INIT_WINDOW_S, self.INIT_WINDOW_S,
                            self.START_ATT_SIGMA_RAD)
        self.ekf = TriadEkf(self.tn, self.alm, self.frame, st.p, st.v, st.C, st.clk, st.P0, self.sigma_sat_m,
                            self.mask_deg, t_ref)
        self.init_sigma_m = float(np.sqrt(np.trace(cov[0, :3, :3])))
        if self._inputs is None:  # world: the baro bias walks from the start
            self.world.baro(int(round((t_ref - self.t0_s) / self.EPOCH_S)))

    def advance_to(self, t_s: float) -> int:
        """Integrate every IMU step that ends at or before ``t_s`` (with the epochs on whole seconds)."""
        n = int(np.floor((t_s - self.t0_s) / self.tn.dt_s + 1e-9)) - self.imu_steps
        self.step_to(self.imu_steps + max(n, 0))
        return max(n, 0)

    def _imu_sample(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """IMU step ``k`` (gyro, accel) (1, 3) each: emulated in blocks (world; journaled) or the journal's."""
        if self._inputs is not None:
            return self._inputs.sample(k)
        g, a = self.world.imu_sample(k, self.tn.dt_s)
        self.journal.imu(k, self.t0_s + (k + 1) * self.tn.dt_s, g, a)
        return g, a

    def step_to(self, k_end: int) -> None:
        """Navigator side: integrate IMU steps up to (excluding) ``k_end``, with the epochs."""
        while self.imu_steps < k_end:
            g, a = self._imu_sample(self.imu_steps)
            if self.ekf is None:
                self._f_sum += a[0]
                self._w_sum += g[0]
            else:
                self.ekf.imu(g, a)
                self.ekf.maybe_propagate()
            self.imu_steps += 1
            if self.imu_steps % self.spe == 0:
                self._epoch(self.imu_steps // self.spe)

    def _station_local(self, src: int) -> tuple[np.ndarray, np.ndarray] | None:
        """The broadcast station ``src`` in the Earth-tied frame and its covariance (3, 3), via the tie."""
        if any(i not in self._broadcast for i in self.tie_ids):
            return None
        ids = self.tie_ids + ([] if src in self.tie_ids else [src])
        pn = np.stack([self._broadcast[i][0] for i in ids])
        sig_n = float(np.sqrt(max(np.max(np.diag(self._broadcast[i][1])) for i in ids)))
        t = ft.tie(pn, sig_n, np.arange(3), self.tie_surveyed_m, self.sigma_tie_m)
        j = ids.index(src)
        return t.stations_m[j], t.cov_m2[j]

    def on_nav(self, msg: dict, phy: dict) -> list[AcEvent]:
        """One nav broadcast -> ``ac_truth`` + the ``ac_estimate`` of ``triad``."""
        from .navigator import plausible  # an implausible nav never reaches the channel or a filter

        if plausible.unusable(msg, float(phy["t_true_s"]), self.bounds, self.stats):
            return []
        src = int(msg["src"])
        s_n = np.asarray(msg["pos_m"], dtype=float)
        cov_l = msg.get("cov_m2", [[0.0] * 3] * 3)
        if not (np.all(np.isfinite(s_n)) and np.all(np.isfinite(np.asarray(cov_l, dtype=float)))):
            self.stats["nav_bad"] += 1
            return []
        got = self.world.measure(phy, msg)
        if got is None:
            self.stats["no_link"] += 1  # [radio]: beyond the horizon or the link budget
            return []
        t_rx, rho, sigma = got
        if not np.isfinite(t_rx) or t_rx < self.t0_s + self.imu_steps * self.tn.dt_s - self.tn.dt_s:
            self.stats["nav_bad_or_late"] += 1
            return []
        # received: it enters the navigator's state (the tie's broadcast positions) whatever follows
        # white range variance beside the nominal sigma: the broadcast clock's and the link's timing
        # variance above the nominal sigma_m (known to the receiver from its SNR)
        cvar = broadcast_clock_var_m2(msg) + link_var_m2(sigma, self.ac.nav.sigma_range_m)
        self.journal.m(t_rx, src, msg["pos_m"], cov_l, cvar, rho)
        return [self.truth_event(t_rx)] + self.measurement(float(t_rx), src, msg["pos_m"], cov_l, cvar, float(rho))

    def measurement(self, t_rx: float, src: int, pos_m, cov_m2, cvar: float, rho: float) -> list[AcEvent]:
        """Navigator side: one measured broadcast (a journal ``m`` entry) -> ``ac_estimate`` / ``ac_status``."""
        self._broadcast[src] = (np.asarray(pos_m, dtype=float), np.asarray(cov_m2, dtype=float))
        self.advance_to(t_rx + self.tn.dt_s)  # the step that contains t_rx
        if self.ekf is None:
            self.stats["nav_before_start"] += 1
            return self.status(t_rx, rx.WAITING, "starting: window fix")
        if self.ekf.t_s < t_rx:
            self.advance_to(self.ekf.t_s + self.tn.dt_s)
        loc = self._station_local(src)
        if loc is None:
            self.stats["nav_no_tie"] += 1
            return []
        return self.station_update(t_rx, *loc, cvar, rho)

    def extra(self) -> dict[str, float]:
        """The estimate's ``extra`` scalars: attitude, clock, IMU, satellites, baro bias, start sigma."""
        e = self.ekf
        roll, pitch, yaw = euler_from_dcm(e.C[0])
        return {"roll_rad": float(roll), "pitch_rad": float(pitch), "yaw_rad": float(yaw),
                "clock_m": float(e.clk[0, 0]), "imu_steps": float(self.imu_steps), "t0_s": self.t0_s,
                "n_sv": float(self.n_sv), "imu_preset": float(list(PRESETS).index(self.imu_name)),
                "imu_rate_hz": float(self.preset.rate_hz), "sat_used": float(self.stats["sat_used"]),
                "baro_bias_m": float(e.bh[0]),
                "init_sigma_m": self.init_sigma_m}
