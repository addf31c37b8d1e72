"""Sans-I/O inertial aircraft for the live process (``--imu PRESET``, algorithm ``ins-ekf``).

World side: the 6-DOF motion (:mod:`aircraft.world.motion`, from the scenario's
``[aircraft.trajectory]`` in the scenario's physical coordinates), the field geometry, the IMU
emulator (seeded per aircraft) and the radio channel (reception time from the sender's true position
and transmit time, pseudorange with the receiver clock and timing noise). Navigator side: one
:class:`aircraft.navigator.ins_ekf.InsEkf` that sees IMU increments, reception times, pseudoranges and
the broadcast (estimated) station positions and covariances only.

The IMU runs on its own fixed grid ``k / rate``: :meth:`advance_to` integrates every step up to a time
(the node calls it continuously with the fleet time, and before each measurement with its reception
time), so no step is skipped whatever the message timing; ``imu_steps`` counts them.

Start (honest, :mod:`aircraft.navigator.ins_start`): until it has a window's worth of broadcasts and
IMU samples, the core buffers both and publishes no estimate (an ``ac_truth`` for every broadcast it
measured); the start is tried at each
measured broadcast (window ending at the last IMU grid time before it), so it depends only on the
sequence of measured broadcasts, not on the node's loop timing. Then the EKF runs from the window's
end over the buffered IMU samples that follow it.

Journal (exact offline re-flight, ``larns reestimate``; aircraft/journal.py): the world hands the
navigator each IMU step's increments and each broadcast it can still use (not late for its IMU time),
and the core journals both in the order the navigator consumed them; :meth:`from_record` rebuilds the
navigator without a world and :meth:`step_to` / :meth:`measurement` re-run it bit for bit. The IMU
samples are emulated in fixed blocks of ``BLOCK`` steps, block ``b`` from its own generator
``(seed, "imu", aircraft, b)``, so sample ``k`` does not depend on how the node's loop chunked time.
"""

from __future__ import annotations

from collections import Counter, deque
from typing import Any

import numpy as np

from nav import errorstate as es
from nav.rotations import euler_from_dcm

from net import streams
from net.clock import broadcast_clock_var_m2
from net.radio import link_var_m2, reception_sigma_m

from .core import InertialCore
from .journal import AcJournal
from .navigator import receiver as rx
from .navigator.ins_ekf import JAC_FORCE_TC_S, InsEkf, InsTuning
from .navigator.ins_start import SideTest, StartConfig, enough, moved_on, radio_fix, start
from .radio_core import radio_record
from .world import clock as wclock
from .world import radio as wradio
from .world.field import Field
from .world.imu import ImuBlocks, ImuEmulator, preset
from .world.motion import Ellipse, Hover, Motion

def motion_from_config(cfg: dict, height_m: float | None = None) -> Motion:
    """6-DOF motion from an ``[aircraft.trajectory]`` table (physical coordinates of the scenario)."""
    kind = cfg.get("kind", "hover")
    if kind == "ellipse":
        return Ellipse(tuple(cfg.get("centre_m", (0.0, 0.0))), tuple(cfg["semi_axes_m"]),
                       float(height_m if height_m is not None else cfg.get("height_m", 1000.0)),
                       float(cfg.get("speed_m_s", 50.0)), np.radians(float(cfg.get("start_angle_deg", 180.0))),
                       float(cfg.get("climb_amp_m", 0.0)), float(cfg.get("climb_period_s", 600.0)))
    if kind == "hover":
        pt = np.asarray(cfg.get("point_m", (0.0, 0.0, height_m if height_m is not None else 1000.0)), dtype=float)
        return Hover(pt, np.radians(float(cfg.get("heading_deg", 0.0))))
    raise ValueError(f"trajectory kind {kind!r} has no 6-DOF model for --imu (ellipse, hover)")


class InsAircraftCore(InertialCore):
    """Pure apart from its own seeded generator: ``advance_to(t)`` and ``on_nav(msg, phy)``; the node's
    side (``lag_s``, ``tick``, ``status_line``, ``summary``) in :class:`aircraft.core.InertialCore`.
    """

    algo = "ins-ekf"
    BLOCK = 100

    def __init__(self, sc, ac, name: str, rng: np.random.Generator, imu: str = "adis16480",
                 height_m: float | None = None, seed: int | None = None, t0_s: float = 0.0, net_clock=None):
        # --- world: motion, field, IMU emulator, channel ---------------------------------------------
        self.net_clock = net_clock  # station 1's oscillator: network time (None: perfect clocks)
        self.ac = ac  # aircraft.config.AircraftConfig: the world reads ac.world, the navigator gets ac.nav
        self.field = Field.from_scenario(sc)
        self.motion = motion_from_config(ac.world.trajectory, height_m if height_m is not None else ac.world.height_m)
        self.rng = rng
        self.imu = ImuEmulator(preset(imu), 1, rng)
        self._imu_blocks = ImuBlocks(self.imu, self.motion, streams.key(sc.seed if seed is None else seed,
                                                                        streams.AIRCRAFT_INS_IMU,
                                                                        streams.name_key(name)), self.BLOCK)
        # --- navigator: what a receiver knows (its init record, aircraft/journal.py) -----------------
        self.bounds = ac.nav.field_bounds  # the deployment plan's plausibility bounds
        record = dict(radio_record(ac.nav, ()), kind="ins", imu=imu, sigma_range_m=float(ac.nav.sigma_range_m),
                      t0_s=float(t0_s))
        self._navigator(record, name)
        self._inputs = None  # the replay's samples (from_record); None: the emulator above
        self.journal = AcJournal(name, record)

    def _navigator(self, record: dict, name: str) -> None:
        self.name = name
        self.t0_s = float(record["t0_s"])  # fleet time of the aircraft's start (motion time 0, first IMU step)
        self.preset = preset(record["imu"])
        cm = wclock.ClockModel()
        self.tn = InsTuning.from_preset(self.preset, sigma_range_m=record["sigma_range_m"], q_b=cm.q_b_m2_s,
                                        q_d=cm.q_d_m2_s3, p0_clock_m=cm.b0_sigma_m, p0_drift_m_s=cm.d0_sigma_m_s,
                                        jac_force_tc_s=JAC_FORCE_TC_S)
        self.L = es.ErrorLayout()
        self.start_cfg = StartConfig()
        self.ekf: InsEkf | None = None  # created by the start (navigator/ins_start.py)
        n_w = int(round(self.start_cfg.window_s / self.tn.dt_s))
        self._imu_buf: deque = deque(maxlen=n_w + 30 * int(round(1.0 / self.tn.dt_s)))  # (step, g, a)
        self._win: list[tuple] = []  # (t_rx, station pos, station cov, rho, var, src) of the start window
        self._sides = SideTest(self.start_cfg, 1)  # which side of the stations' plane (disjoint windows)
        self._last_window_end = -np.inf
        self._guess = None
        self.imu_steps = 0
        self.seq: Counter[str] = Counter()
        self.stats: Counter[str] = Counter()
        self._pacer = rx.StatusPacer()

    @classmethod
    def from_record(cls, record: dict, name: str, inputs) -> "InsAircraftCore":
        """The navigator alone, fed the IMU samples of a journal (:class:`aircraft.journal.Inputs`)."""
        core = cls.__new__(cls)
        core._navigator(record, name)
        core._inputs = inputs
        core.journal = None
        return core

    def _imu_sample(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """IMU step ``k``: (gyro, accel) increments (1, 3) each, emulated in blocks (world; journaled)
        or, in a replay, the journal's."""
        if self._inputs is not None:
            return self._inputs.sample(k)
        g, a = self._imu_blocks.sample(k, self.tn.dt_s)
        self.journal.imu(k, self.t0_s + (k + 1) * self.tn.dt_s, g, a)
        return g, a

    def advance_to(self, t_s: float) -> int:
        """Integrate every IMU step that ends at or before ``t_s``; returns how many were run."""
        n = int(np.floor((t_s - self.t0_s) / self.tn.dt_s + 1e-9)) - self.imu_steps
        if n <= 0:
            return 0
        self.step_to(self.imu_steps + n)
        return n

    def step_to(self, k_end: int) -> None:
        """Navigator side: integrate IMU steps up to (excluding) ``k_end``."""
        while self.imu_steps < k_end:
            g, a = self._imu_sample(self.imu_steps)
            if self.ekf is None:
                self._imu_buf.append((self.imu_steps, g, a))
            else:
                self.ekf.imu(g, a)
                self.ekf.maybe_propagate()
            self.imu_steps += 1

    def _try_start(self, t_rx: float) -> bool:
        """Start the EKF at the last IMU grid time before ``t_rx`` if the window before it holds enough
        measured broadcasts (:func:`aircraft.navigator.ins_start.enough`); else drop the ones older
        than the window."""
        dt, cfg = self.tn.dt_s, self.start_cfg
        n_w = int(round(cfg.window_s / dt))
        k_e = int(np.ceil((t_rx - self.t0_s) / dt - 1e-9)) - 1  # window end: grid step k_e, t_e < t_rx
        t_e = self.t0_s + k_e * dt
        if t_e < self._last_window_end + cfg.window_s - 1e-9:  # the side test's windows are disjoint
            return False
        self._win = [w for w in self._win if w[0] > t_e - cfg.window_s]
        win = [w for w in self._win if w[0] <= t_e]
        if k_e < n_w or not win or not enough([w[0] for w in win], [w[5] for w in win], cfg):
            return False
        self.advance_to(t_e)
        steps = {k: (g, a) for k, g, a in self._imu_buf}
        if any(k not in steps for k in range(k_e - n_w, k_e)):
            self.stats["start_imu_missing"] += 1
            return False
        g = np.array([steps[k][0] for k in range(k_e - n_w, k_e)])
        a = np.array([steps[k][1] for k in range(k_e - n_w, k_e)])
        t, S, Cs, rho, var, _ = (np.array(x) for x in zip(*win))
        fix = radio_fix(t, S, Cs, rho[None], var, t_e, self.tn.sigma_range_m, cfg, self.tn.q_b, self.tn.q_d,
                        None if self._guess is None else moved_on(*self._guess, t_e - self._last_window_end))
        self._sides.add(fix)
        self._last_window_end = t_e
        self.stats["start_windows"] += 1
        if not self._sides.decided()[0]:
            self._guess = (fix, self._sides.side())
            return False
        st = start(self.L, self.tn, fix, self._sides.side(), g, a, t_e, cfg)
        self.ekf = InsEkf(self.tn, self.L, st.p, st.v, st.C, st.clock, st.P0, st.tau, st.sign, t0_s=t_e)
        self.stats["start_measurements"] = len(win)
        self.stats["start_at_ms"] = int(round(1e3 * t_e))
        for k in sorted(steps):  # IMU samples the node already integrated past the window's end
            if k >= k_e:
                self.ekf.imu(*steps[k])
                self.ekf.maybe_propagate()
        self._imu_buf.clear()
        self._win = []
        return True

    def truth_n(self, t_s: float):
        p, v, C = self.field.truth(self.motion, np.array([t_s - self.t0_s]))
        return p[0], v[0], C[0]

    def measure(self, phy: dict, msg: dict | None = None,
                noise: bool = True) -> tuple[float, float, float] | None:
        """Channel layer: true reception time, pseudorange and one-way timing sigma (m) from the
        station-stamped transmit time corrected by the broadcast clock correction
        (:func:`net.clock.broadcast_time_error_s`), read on the receiver clock of the scenario; ``None``
        where the scenario's ``[radio]`` has no link (:func:`net.radio.reception_sigma_m`).
        ``noise=False``: without the timing noise (its one draw is then :meth:`noise_m`, taken only
        for a broadcast the navigator uses, so that a broadcast dropped as late live, and absent from
        the re-flight, consumes no draw)."""
        p_tx = np.asarray(phy["pos_m"], float)
        t_tx = float(phy["t_true_s"])
        t_rx, p = wradio.heard(lambda t: self.truth_n(t)[0], p_tx, t_tx)
        w = self.ac.world
        sigma = reception_sigma_m(p_tx, p, w.radio, w.sigma_m)
        if sigma is None:
            return None
        rho = wradio.pseudorange_m(p, p_tx, t_tx, t_rx, msg, w.clock, self.net_clock)
        return t_rx, rho + (self.noise_m(sigma) if noise else 0.0), sigma

    def noise_m(self, sigma_m: float) -> float:
        """One draw of the channel's timing noise of sigma ``sigma_m`` (m)."""
        return sigma_m * float(self.rng.standard_normal())

    def on_nav(self, msg: dict, phy: dict) -> list[AcEvent]:
        """One nav broadcast -> ``ac_truth`` + the ``ac_estimate`` of ``ins-ekf`` (with attitude in
        ``extra``). World side: the channel layer; the navigator gets (and the journal records) only
        the broadcasts it can still use (not late for its IMU time)."""
        from .navigator import plausible  # an implausible nav never reaches the channel or a filter

        if plausible.unusable(msg, float(phy["t_true_s"]), self.bounds, self.stats):
            return []
        got = self.measure(phy, msg, noise=False)
        if got is None:
            self.stats["no_link"] += 1  # [radio]: beyond the horizon or the link budget
            return []
        t_rx, rho, sigma = got
        s = np.asarray(msg["pos_m"], dtype=float)
        t_nav = self.t0_s + self.imu_steps * self.tn.dt_s if self.ekf is None else self.ekf.t_s
        if not (np.all(np.isfinite(s)) and np.isfinite(t_rx) and np.isfinite(rho)) or t_rx < t_nav - self.tn.dt_s:
            self.stats["nav_bad_or_late"] += 1
            return []
        rho += self.noise_m(sigma)
        cov = msg.get("cov_m2", [[0.0] * 3] * 3)
        # white range variance beside the nominal sigma: the broadcast clock's and the link's timing
        # variance above the nominal sigma_m (known to the receiver from its SNR)
        cvar = broadcast_clock_var_m2(msg) + link_var_m2(sigma, self.ac.nav.sigma_range_m)
        self.journal.m(t_rx, int(msg["src"]), msg["pos_m"], cov, cvar, rho)
        return [self.truth_event(t_rx)] + self.measurement(float(t_rx), int(msg["src"]), msg["pos_m"], cov, cvar,
                                                           float(rho))

    def measurement(self, t_rx: float, src: int, pos_m, cov_m2, cvar: float, rho: float) -> list[AcEvent]:
        """Navigator side: one measured broadcast (a journal ``m`` entry) -> ``ac_estimate`` / ``ac_status``."""
        s = np.asarray(pos_m, dtype=float)
        cov = np.asarray(cov_m2, dtype=float)
        if self.ekf is None and not self._try_start(t_rx):  # still listening: keep it for the start
            self._win.append((t_rx, s, cov, rho, self.tn.sigma_range_m**2 + cvar, str(src)))
            self.stats["start_buffered"] += 1
            return self.status(t_rx, rx.WAITING, "starting: collecting broadcasts")
        self.advance_to(t_rx + self.tn.dt_s)  # the step that contains t_rx
        return self.station_update(t_rx, s, cov, cvar, rho)

    def extra(self) -> dict[str, float]:
        """The estimate's ``extra`` scalars: attitude, clock, IMU steps, start time (and the tilt)."""
        e = self.ekf
        roll, pitch, yaw = euler_from_dcm(e.C[0])
        extra = {"roll_rad": float(roll), "pitch_rad": float(pitch), "yaw_rad": float(yaw),
                 "clock_m": float(e.clk[0, 0]), "imu_steps": float(self.imu_steps), "t0_s": self.t0_s}
        if e.L.tilt:
            extra.update(tilt_1=float(e.tau[0, 0]), tilt_2=float(e.tau[0, 1]))
        return extra
