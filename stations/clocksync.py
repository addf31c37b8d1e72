"""Decentralized network time: each station estimates its own clock against station 1's (pure, sans-I/O).

Network time is station 1's clock, as station 1 is the origin of the frame. Station ``m`` estimates
``theta_m(t) = t - T(t)`` (its local time ``t`` minus network time ``T``) and its fractional frequency
``f_m = d theta_m / dt`` with the two-state clock model of ``net/clock.py`` (state ``[theta, f]``,
``F = [[1, dt], [0, 1]]``, ``Q(dt)`` from the oscillator class ``q_wf``, ``q_rw``).

Measurements:

* **Two-way time transfer** inside every range exchange (initiator ``m``, responder ``j``; ``t1`` request
  sent and ``t4`` reply received on ``m``'s clock, ``t2`` request received and ``t3`` reply sent on
  ``j``'s clock)::

      dtheta = ((t4 - t3) - (t2 - t1)) / 2 = theta_m - theta_j      (at the exchange's midpoint)
      range  = c ((t4 - t1) / (1 + f_m) - (t3 - t2) / (1 + f_j)) / 2

  exact for linear clocks whatever their offsets and frequencies (the midpoints ``(t1 + t4) / 2`` and
  ``(t2 + t3) / 2`` are the same true instant); each arrival's timing noise ``sigma_t = sqrt(2)
  sigma_d / c`` gives ``var(dtheta) = sigma_d^2 / c^2``. Both ends use the exchange: the initiator on
  the reply, the responder from the initiator's nav broadcast (which carries ``dtheta``).
* An exchange heard in a peer's nav (``[peer, range, t_mid, dtheta]``, ``t_mid`` on the sender's clock)
  is the same measurement between two other clocks, placed in network time by this filter's own
  estimate of the sender's clock (a sender not in the filter yet: by its broadcast **clock correction**
  ``[t_ref, theta, f, P_tt, P_tf, P_ff]``); the variance of that time is charged through the two
  clocks' frequency difference while small, else the exchange waits until that clock is known
  (``on_exchange``, ``t_var_s2``).
* **Coarse sync** while the clock is unknown to more than ``coarse_gate_s``: a nav broadcast received
  at ``t_rx`` with transmit stamp ``t_tx`` gives ``theta_m = t_rx - (t_tx - theta_j(t_tx)) - d / c`` with
  the distance ``d`` unknown (variance ``(coarse_range_m / c)^2``): microseconds from the first nav heard.

**Ensemble network time** (no station is special). The filter's states are placed against station 1's
clock (its coordinates: ``theta_1 = f_1 = 0``, and the time axis ``T`` on which exchanges are placed and
slots scheduled), but *network time* - what the broadcast clock corrections, the estimates and the
truth refer to - is the ensemble ``E`` of :class:`net.clock.TimeScale`: the weighted mean of the member
clocks plus a phase and a rate term that keep it continuous when the members change. It starts as
station 1's clock alone (the founder defines time until the others are known); once per second of
``T`` each station re-evaluates the members from what it hears (:meth:`ClockEstimator._membership`):
a clock enters (weight from zero) once its offset against the ensemble is known to ``ENTER_SD_S``, a
member not heard in an exchange for ``LEAVE_S`` leaves (dated back to its last exchange, where its
offset was last measured), and the weights are renormalized, continuous in phase and rate
(:func:`net.clock.ensemble_change`). Weights are ``1 / sigma_y^2`` of each clock's
class (one class per field: equal weights). Every station's filter is (up to the navs it missed) the
centralized one, so every station computes the same scale; its changes are logged
(``scale_log``) so the world side evaluates the same definition on the true clocks.

**Multi-hop fields** (docs/sync.md "Multi-hop network time"). A station's filter holds the clocks it
hears and those its neighbours' navs name (its two-hop neighbourhood, dense), not the field. A station
that never hears station 1 defines time over the clocks around it (``_membership``), a definition
that does not descend from the founders': until it takes one that does from a peer (in full, at its
next steering) it broadcasts ``UNROOTED_SD_S`` more, and no station whose definition descends from
the founders' steers on it (``on_peer_scale``). Its filter's time axis (station 1's clock, never
measured there) is anchored on its peers' broadcasts (``_anchor``) whenever its own clock against it
is unknown to the coarse gate. A clock enters a definition only once its frequency is known to
``ENTER_FREQ_SD`` as well: a rate term frozen from worse frequencies drove the definitions of a
multi-hop field apart. Once per second each station moves its definition to the lazy inverse-variance
weighted average of its neighbourhood's (:func:`consensus_step`), so the definitions' disagreement
falls geometrically over the graph.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S
from net.clock import TimeScale, ensemble_change, transition

C = SPEED_OF_LIGHT_M_S
ENTER_SD_S = 2e-9  # a clock enters the ensemble once its offset against it is known to 2 ns (1 sigma)
ENTER_FREQ_SD = 1.5e-10  # ... and its frequency to 1.5e-10 (docs/sync.md "Multi-hop network time")
# consensus on the definition (docs/sync.md "One time scale", "Multi-hop network time"): once per second
# of T the scale's phase moves by the lazy weighted average of the phase disagreements with the peers'
# definitions (consensus_step) and its rate by STEER_R times the weighted mean rate disagreement, which
# the peers' corrections carry (their frequency term) against our estimate of the same clocks' rates: a
# definition that drifts against the field's is corrected from the drift measured, not learnt by
# integrating the phase error (docs/sync.md)
STEER_P = 0.3  # the least gain of the phase (consensus_step)
STEER_R = 0.3
STEER_GATE_S = 2e-9  # a peer's correction and our estimate of its clock both known to 2 ns (1 sigma)
STEER_RATE_GATE = 1e-9  # ... and a rate disagreement used only where both rates are known to 1 ns/s
AGREED_LIMIT_S = 1e-5  # largest disagreement an agreed definition steers on
UNAGREED_LIMIT_S = 1.0  # ... and one not yet agreed adopts (a sanity bound: clocks are set to ms)
UNAGREED_SD_S = 1e-6  # a definition not yet compared with any peer's: broadcast offsets carry 1 us more
# a definition that does not descend from the founders' (docs/sync.md "Multi-hop network time"): formed by
# a station that has heard neither station 1 nor a definition that does, over the clocks around it, it
# lies as far from the field's as the mean of those clocks' offsets (milliseconds). Broadcast offsets
# carry 1 ms more while it is so; no station whose definition descends from the founders' steers on it
UNROOTED_SD_S = 1e-3
SCALE_LOG_MAX = 4096  # definitions kept for the world side (the recent ones; about an hour of steering)
LEAVE_S = 5.0  # a member not heard in any exchange for 5 s of network time leaves the ensemble
# a station that powers on while station 1 (the filter's coordinate clock) is silent anchors its filter
# on its peers' broadcast corrections: their offsets against the ensemble stand for their offsets
# against that coordinate clock, within ANCHOR_SD_S (the field keeps both continuous: ns apart)
ANCHOR_SD_S = 1e-6
# a clock step (a jump of a peer's phase, docs/sync.md "A clock that steps"): a time transfer between
# two members of the time scale whose normalized innovation squared exceeds STEP_NIS (chi-square 1 dof,
# p = 1e-7) is not used. A clock whose last STEP_N transfers, with STEP_PARTNERS partners or more, were
# all refused with innovations that agree (one sign, spread within STEP_AGREE of the smallest: a step
# shows the same jump to every partner, NLOS excesses scatter in sign and size) is re-initialized (its
# state decorrelated, its phase and frequency variances back to the class prior): it leaves the
# ensemble as a silent member does and re-enters once known again
STEP_NIS = 28.4
STEP_N = 4
STEP_AGREE = 0.1
STEP_PARTNERS = 3
STEP_KNOWN_S = 1e-7  # ... judged only where the predicted transfer is known to 100 ns, not while the
# clocks are acquired (seed000 world seed 2: the first seconds' transfers, known to ~1 us after the
# coarse sync, come out ~6 sigma off, NIS 32-38, until the exchanges have refined them)


# NumPy's LAPACK gufuncs behind np.linalg (a private module: where it is missing, the public functions)
_umath_linalg = getattr(np.linalg, "_umath_linalg", None)


def _cholesky(S: np.ndarray) -> np.ndarray:
    """``np.linalg.cholesky`` of a real (m, m) ``S`` without its wrapper (the same LAPACK call, so the
    same factor; its per-call cost is most of the call at m = 9): ``LinAlgError`` unless positive definite."""
    if _umath_linalg is None:
        return np.linalg.cholesky(S)
    L = _umath_linalg.cholesky_lo(S, signature="d->d")
    if math.isnan(L.item(-1)):  # LAPACK's failure leaves the whole factor NaN
        raise np.linalg.LinAlgError("Matrix is not positive definite")
    return L


def _solve(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``np.linalg.solve`` of a real (m, m) ``A`` and (m, k) ``B`` without its wrapper (the same LAPACK
    ``gesv``); a singular ``A`` gives NaN (``A`` here: a Cholesky factor, checked)."""
    if _umath_linalg is None:
        return np.linalg.solve(A, B)
    return _umath_linalg.solve(A, B, signature="dd->d")


def consensus_step(d_s: np.ndarray, var_s2: np.ndarray) -> tuple[float, float, float]:
    """One steering of a definition of network time toward its neighbourhood's (pure).

    Parameters
    ----------
    d_s : (n,) measured disagreements ``N_peer - N_me`` with the peers' definitions, s (n >= 1).
    var_s2 : (n,) their noise variances, s^2 (> 0).

    Returns
    -------
    ``(d, g, R)``: the inverse-variance weighted mean disagreement ``d`` (s), the gain ``g`` by which the
    definition's phase moves (``N_me += g d``) and the variance ``R`` of ``d`` (s^2).

    The new definition is the weighted average of the neighbourhood's, ours counted as one more member
    with the peers' mean weight: ``g = n / (n + 1)`` (a lazy average: on a connected graph the
    disagreement falls geometrically every cycle, at the rate of the graph's second eigenvalue, instead of
    a fixed ``STEER_P`` = 0.3 of it, the rule until issue 33's item 3). Its noise is kept out by the
    scalar Wiener factor ``d^2 / (d^2 + R)`` down to ``STEER_P``, the former fixed gain, as the least
    gain: below it a definition within its noise of the neighbourhood's is hardly steered and drifts
    with its members' rates (mh60 world seeds 3-4: a plateau of 4 ns, docs/sync.md). The measurement errors of one
    station's disagreements share that station's estimate of its own definition (its members' clocks),
    so they are not taken as independent: ``R = (sum_j w_j sigma_j)^2 / (sum_j w_j)^2``, ``w_j = 1 /
    sigma_j^2``, the variance of the weighted mean whatever their correlation.
    """
    w = 1.0 / np.maximum(np.asarray(var_s2, float), 1e-30)
    sw = float(w.sum())
    d = float(w @ np.asarray(d_s, float)) / sw
    R = (float(np.sqrt(w).sum()) / sw) ** 2
    n = len(w)
    g = n / (n + 1.0) * d * d / (d * d + R) if d * d + R > 0 else 0.0
    return d, max(g, STEER_P), R


def _one_jump(seen: list[tuple[float, int]]) -> bool:
    """The refused innovations of one clock, ``(jump_s, partner)``, show one jump: with at least
    ``STEP_PARTNERS`` partners (an NLOS link repeats its excess), one sign, spread within
    ``STEP_AGREE`` of the smallest."""
    if len({p for _, p in seen}) < STEP_PARTNERS:
        return False
    jumps_s = [j for j, _ in seen]
    lo, hi = min(jumps_s), max(jumps_s)
    if lo * hi <= 0.0:
        return False
    return hi - lo <= STEP_AGREE * min(abs(lo), abs(hi))


@dataclass(frozen=True)
class ClockModel:
    """What a station knows of its oscillator class (data-sheet values, not its realized clock)."""

    q_wf_s: float = 0.0
    q_rw_per_s: float = 0.0
    offset_sigma_s: float = 0.0
    freq_sigma: float = 0.0


def predict_correction(corr, t_s: float, model: ClockModel) -> tuple[float, float]:
    """A broadcast clock correction ``[t_ref, theta, f, P_tt, P_tf, P_ff]`` evaluated at ``t_s`` (same
    clock as ``t_ref``): offset (s) and its variance (s^2), process noise of ``model`` included (twice:
    the station's oscillator and network time's, station 1's, both wander)."""
    t_ref, th, f, ptt, ptf, pff = (float(v) for v in corr)
    dt = t_s - t_ref
    _, Q = transition(dt, model.q_wf_s, model.q_rw_per_s)
    var = ptt + 2.0 * dt * ptf + dt * dt * pff + 2.0 * Q[0, 0]
    return th + f * dt, max(var, 0.0)


def _block_at(P0: np.ndarray, k1: int, k2: int, dt_s: float, Q: tuple[float, float, float] | None
              ) -> tuple[float, float, float, float]:
    """The 2x2 block ``(P_tt, P_tf, P_ft, P_ff)`` between the clocks at state-block indices ``k1``, ``k2``
    of ``F P0 F^T + Q (x) (I + 1 1^T)`` over ``dt_s`` (``Q = Q(dt_s)`` as ``(Q_tt, Q_tf, Q_ff)``; ``dt_s <= 0``:
    ``P0``'s block). The same operations, in the same order, as the dense prediction (:func:`_propagate`),
    so the values are bit for bit those of its block."""
    i, j = 2 * k1, 2 * k2
    tt, tf, ft, ff = P0.item(i, j), P0.item(i, j + 1), P0.item(i + 1, j), P0.item(i + 1, j + 1)
    if dt_s > 0:
        tt, tf = tt + dt_s * ft, tf + dt_s * ff  # F M: row theta += dt row f
        tt, ft = tt + dt_s * tf, ft + dt_s * ff  # (F M) F^T: column theta += dt column f
        a, b, c = Q  # own wander on the diagonal blocks, network time's everywhere
        g = 2.0 if k1 == k2 else 1.0
        tt, tf, ft, ff = tt + g * a, tf + g * b, ft + g * b, ff + g * c
    return tt, tf, ft, ff


def _on_states(c: np.ndarray) -> np.ndarray:
    """Coefficients ``c`` (n,) over the clocks as two rows over the states (2n, 2): ``c`` on the
    offsets (column 0) and on the frequencies (column 1)."""
    V = np.zeros((2 * len(c), 2))
    V[0::2, 0] = c
    V[1::2, 1] = c
    return V


def _propagate(P: np.ndarray, dt_s: float, Q: tuple[float, float, float]) -> None:
    """In place: ``P <- F P F^T + Q (x) (I + 1 1^T)`` for clocks in 2x2 blocks (``F = [[1, dt], [0, 1]]``
    per block; the ``1 1^T`` part is network time's own wander, common to every offset)."""
    P[0::2, :] += dt_s * P[1::2, :]
    P[:, 0::2] += dt_s * P[:, 1::2]
    qtt, qtf, qff = Q
    for a, b, q in ((0, 0, qtt), (0, 1, qtf), (1, 0, qtf), (1, 1, qff)):
        blk = P[a::2, b::2]
        blk += q
        np.einsum("ii->i", blk)[...] += q


class ClockEstimator:
    """Network clock filter of one station (see module docstring): a Kalman filter of every known
    station's ``[theta, f]`` against network time, fed by all two-way exchanges the station takes part
    in or hears in the nav broadcasts, plus coarse one-way nav timing while a clock is unknown.

    States are functions of network time ``T``; the station converts its local time with its own
    estimate, ``T = t - theta_me(T)``. Station 1 (``theta = f = 0``) is not a state. Network time is
    itself an oscillator: ``theta_k = x_k - x_1`` wanders with its own noise and station 1's, which
    all stations share, so the process noise is ``Q(dt) (x) (I + 1 1^T)``.

    **Cost.** The filter state ``x`` lives at ``T_s``; its covariance is kept at a reference time
    ``T0 <= T_s`` as ``P0``, with ``P(T_s) = F P0 F^T + Q(T_s - T0) (x) (I + 1 1^T)`` (``F`` the
    block-diagonal transition over ``T_s - T0``: every clock shares the model and the step, and the
    exact discretization composes, so one prediction over ``T_s - T0`` equals the chain of per-input
    predictions). A time-transfer row touches two clocks, so ``P(T_s) h`` is four columns of ``P0``
    mapped through ``F`` and ``Q``: O(n). The scalar update with the optimal gain,
    ``P - K S K^T = P - w w^T`` with ``w = P h / sqrt(S)`` (the Joseph form's value for a scalar
    measurement), moves to the reference time as ``P0 - v v^T``, ``v = F^{-1} w``: one rank-1 pass,
    exactly symmetric. ``P0`` is moved to ``T_s`` (one O(n^2) prediction, symmetrized) when
    ``T_s - T0`` exceeds ``rebase_s`` (about once per TDMA cycle) or when ``P`` is read. Equal to the
    dense filter (predict every input, expanded Joseph update) to rounding: ``tests/stations/test_sync.py``.
    A slot's transfers (a nav's entries under the poll) are one batch update (:meth:`on_exchanges`).

    Parameters
    ----------
    station_id : this station (1: the reference, exact). model : oscillator class (prior and noise of
    every clock). t0_s : local time of the prior. sigma_d_m : two-way range noise (sets the TWTT noise).
    coarse_range_m, coarse_gate_s : coarse one-way sync (see module docstring). rebase_s : largest
    ``T_s - T0`` before ``P0`` is moved to ``T_s``, s. time_gate : largest variance that the
    uncertain network time of an exchange may add to it, as a fraction of the time-transfer
    variance; an exchange whose time is less certain waits up to ``defer_s`` (s of network time) for
    its clock to be known (``on_exchange``). step_nis : the clock-step gate (``STEP_NIS``; inf: none).
    """

    def __init__(self, station_id: int, model: ClockModel, t0_s: float, sigma_d_m: float,
                 coarse_range_m: float = 5000.0, coarse_gate_s: float = 1e-6, rebase_s: float = 1.0,
                 time_gate: float = 0.01, defer_s: float = 3.0, step_nis: float = STEP_NIS):
        self.id = station_id
        self.step_nis = float(step_nis)
        self.ref = station_id == 1
        self.model = model
        self.T_s = float(t0_s)
        self.index: dict[int, int] = {}
        self.x = np.zeros(0)
        self._P0 = np.zeros((0, 0))  # covariance at self._T0 (see the class docstring)
        self._T0 = self.T_s
        self._q_dt, self._q = 0.0, (0.0, 0.0, 0.0)  # the last Q(dt) (_Q)
        self._members_of, self._members_w, self._members_neg = None, {}, np.zeros(0)  # (_members)
        self._members_c: list[float] = []
        self.rebase_s = float(rebase_s)
        self.var_z = (sigma_d_m / C) ** 2
        self.coarse_var = (coarse_range_m / C) ** 2
        self.coarse_gate_s = coarse_gate_s
        self.n_updates = 0
        self.n_coarse = 0
        self.n_untimed = 0  # exchanges dropped: their network time too uncertain (on_exchange)
        self.n_step_refused = 0  # time transfers refused by the step gate (STEP_NIS)
        self.n_reinit = 0  # clocks re-initialized after STEP_N refusals in a row that show one jump
        self._last_nu = 0.0  # the innovation of the last scalar update (refused or not), s
        self._refused: dict[int, list] = {}  # clock -> (its jump as seen, s; partner) of the refusals in a row
        self.n_deferred = 0  # exchanges kept until their time was known (on_exchange)
        self.time_gate = time_gate
        self.defer_s = defer_s
        self._pending: list[tuple[int, int, float, float, float, float | None]] = []
        self._retry_T = -np.inf
        self.exact = model.offset_sigma_s == 0 and model.freq_sigma == 0 and model.q_wf_s == 0 \
            and model.q_rw_per_s == 0  # perfect clocks: nothing to estimate
        # ensemble network time (module docstring): station 1's clock until the others are known
        self.scale = TimeScale(((1, 1.0),), T_ref_s=self.T_s)
        self.scale_log: list[TimeScale] = [self.scale]
        self._heard_T: dict[int, float] = {}  # network time of the last exchange of each clock
        self._stepped_T: dict[int, float] = {}  # re-initialized clock -> its last exchange before the step
        self._stepped_state: dict[int, tuple[float, float, float]] = {}  # ... and (T, theta, f) before it
        # (N_peer - N_me (s), its rate (s/s; nan: not known well enough), peer's tier, variance s^2) since the last tick
        self._disagree: list[tuple[float, float, int, float]] = []
        # variance of our definition against the field's, added to the broadcast offset's: unknown (1 us)
        # until the first steering, which adopts the field's definition in full; then what is left of
        # the last measured disagreement
        self._scale_var_s2 = UNAGREED_SD_S**2
        # does our definition descend from the founders' (station 1's clock at power-on, then the changes
        # and steerings that keep it continuous)? Every station's does at power-on; one redefined over the
        # clocks around it (none of its members heard: _membership) does not, until it takes the definition
        # of a peer whose does (UNROOTED_SD_S)
        self._rooted = True
        self._tick_T = math.floor(self.T_s)
        self._t0_local = float(t0_s)
        self._ref_heard_local = -math.inf  # local time of the last nav heard from station 1
        self.n_anchor = 0  # navs used as absolute anchors (station 1 silent, own clock unknown)
        if not self.ref:
            self._add(station_id)

    # ------------------------------------------------------------------ covariance storage
    @property
    def P(self) -> np.ndarray:
        """Covariance (n, n) of ``x`` at ``T_s`` (moves the stored reference to ``T_s``: O(n^2))."""
        self._rebase()
        return self._P0

    @P.setter
    def P(self, value: np.ndarray) -> None:
        self._P0 = np.asarray(value, float)
        self._T0 = self.T_s

    def _Q(self, dt_s: float) -> tuple[float, float, float]:
        """``Q(dt)`` of one clock (``dt >= 0``) as ``(Q_tt, Q_tf, Q_ff)`` (``net.clock.transition``); the
        last one is kept (an input reads it several times at the same ``T_s - T0``)."""
        if dt_s != self._q_dt:
            qw, qr = self.model.q_wf_s, self.model.q_rw_per_s
            self._q_dt, self._q = dt_s, (qw * dt_s + qr * dt_s**3 / 3.0, qr * dt_s * dt_s / 2.0, qr * dt_s)
        return self._q

    def _rebase(self) -> None:
        """``P0 <- F P0 F^T + Q (x) (I + 1 1^T)`` over ``T_s - T0``; then ``T0 = T_s``."""
        dt = self.T_s - self._T0
        self._T0 = self.T_s
        if dt <= 0 or not len(self.x):
            return
        P = self._P0
        _propagate(P, dt, self._Q(dt))
        self._P0 = 0.5 * (P + P.T)

    def _cov(self, k1: int, k2: int) -> tuple[float, float, float, float]:
        """``P(T_s)`` between the clocks at state-block indices ``k1``, ``k2`` as scalars
        ``(P_tt, P_tf, P_ft, P_ff)``: the 2x2 block of ``P0`` through ``F`` and ``Q``, O(1)
        (:func:`_block_at`)."""
        dt = self.T_s - self._T0
        return _block_at(self._P0, k1, k2, dt, self._Q(dt) if dt > 0 else None)

    def _var(self, ks: list[int], signs: list[float], dt_h: float) -> float:
        """``h P(T_s) h^T`` for the sparse row ``h = sum_i s_i e_{k_i} (x) [1, dt_h]``, O(1) (scalar sums:
        equal to the dense product to rounding; the gates that read it are not near a tie)."""
        P0, dt = self._P0, self.T_s - self._T0
        q = self._Q(dt) if dt > 0 else None
        var = 0.0
        for i, (ki, si) in enumerate(zip(ks, signs)):  # P(T_s) is symmetric: each pair i < j twice
            for j in range(i, len(ks)):
                tt, tf, ft, ff = _block_at(P0, ki, ks[j], dt, q)
                var += (1.0 if j == i else 2.0) * si * signs[j] * (tt + dt_h * (tf + ft) + dt_h * dt_h * ff)
        return var

    def _PH(self, ks: list[int], signs: list[float], dt_h: float) -> tuple[list[float], list[float]]:
        """``P(T_s) h`` (n,) for the sparse row ``h = sum_i s_i e_{k_i} (x) [1, dt_h]`` (block indices
        ``ks``, signs ``s``), and ``F^{-1} P(T_s) h`` (n,) (the same at the reference time ``T0``): columns
        of ``P0`` mapped through ``F`` and ``Q``, O(n).

        With ``F = [[1, dt], [0, 1]]`` per block over ``dt = T_s - T0`` and ``g = Q [1, dt_h]``:
        ``P(T_s) h = F (P0 F^T h) + g (x) (sum_i s_i 1 + sum_i s_i e_{k_i})`` (network time's wander on
        every block, each clock's own on its block), and ``F^{-1} P(T_s) h = P0 F^T h + F^{-1} g (x) (...)``.
        ``P0 F^T h`` is one matrix-vector product with the dense ``F^T h``. Both as lists of floats."""
        dt = self.T_s - self._T0
        n = len(self.x)
        hf = [0.0] * n  # F^T h: s [1, dt + dt_h] on the touched blocks
        for k, sg in zip(ks, signs):
            hf[2 * k] += sg
            hf[2 * k + 1] += sg * (dt + dt_h)
        y0 = (self._P0 @ hf).tolist()
        if dt <= 0:
            return y0, y0
        qtt, qtf, qff = self._Q(dt)
        gt, gf = qtt + dt_h * qtf, qtf + dt_h * qff  # Q [1, dt_h]
        it = gt - dt * gf  # F^{-1} g: [gt - dt gf, gf]
        tot = float(sum(signs))
        ct, cf, ci = tot * gt, tot * gf, tot * it
        # blockwise on floats (9 clocks: NumPy's per-call cost dominates): F y0 and y0, plus the wander
        z = y0
        y, v = z[:], z[:]
        for i in range(0, n, 2):
            t, f = z[i], z[i + 1]
            y[i], y[i + 1] = t + dt * f + ct, f + cf
            v[i], v[i + 1] = t + ci, f + cf
        for k, sg in zip(ks, signs):
            y[2 * k] += sg * gt
            y[2 * k + 1] += sg * gf
            v[2 * k] += sg * it
            v[2 * k + 1] += sg * gf
        return y, v

    def _add(self, sid: int) -> int:
        k = self.index.get(sid)
        if k is None:
            self._rebase()
            k = self.index[sid] = len(self.index)
            n = 2 * len(self.index)
            P = np.zeros((n, n))
            P[: n - 2, : n - 2] = self._P0
            P[n - 2, n - 2] = self.model.offset_sigma_s**2
            P[n - 1, n - 1] = self.model.freq_sigma**2
            self._P0 = P
            self.x = np.concatenate([self.x, [0.0, 0.0]])
        return k

    def _own(self) -> tuple[float, float, float, float, float]:
        """Own ``theta, f`` at ``T_s`` and their covariance ``P_tt, P_tf, P_ff``."""
        if self.ref:
            return 0.0, 0.0, 0.0, 0.0, 0.0
        k = self.index[self.id]
        ptt, ptf, _, pff = self._cov(k, k)
        return self.x[2 * k], self.x[2 * k + 1], ptt, ptf, pff

    def _own_x(self) -> tuple[float, float]:
        if self.ref:
            return 0.0, 0.0
        k = 2 * self.index[self.id]
        x = self.x
        return x.item(k), x.item(k + 1)

    # ------------------------------------------------------------------ time conversions
    @property
    def known(self) -> bool:
        """Own clock known to better than the coarse gate (station 1: always)."""
        return self.ref or self._own()[2] <= self.coarse_gate_s**2

    @property
    def offset_var_s2(self) -> float:
        return self._own()[2]

    def network_time(self, t_local_s: float) -> float:
        """Estimated network time at local time ``t_local_s``."""
        a, f = self._own_x()
        return (t_local_s - a + f * self.T_s) / (1.0 + f)

    def local_time(self, t_net_s: float) -> float:
        """Local time at which the estimated network time is ``t_net_s``."""
        a, f = self._own_x()
        return t_net_s + a + f * (t_net_s - self.T_s)

    def offset_at(self, t_local_s: float) -> float:
        """Estimated own offset (local minus network time) at local time ``t_local_s``, s."""
        return t_local_s - self.network_time(t_local_s)

    def freq(self) -> float:
        return float(self._own_x()[1])

    def freq_var(self) -> float:
        """Variance of the own fractional frequency against network time (0 for the reference clock)."""
        return float(self._own()[4])

    def variance_at(self, t_local_s: float) -> float:
        """Own offset variance at local ``t_local_s`` (predicted; the state unchanged), s^2."""
        _, _, ptt, ptf, pff = self._own()
        dt = self.network_time(t_local_s) - self.T_s
        _, Q = transition(dt, self.model.q_wf_s, self.model.q_rw_per_s)
        return float(ptt + 2 * dt * ptf + dt * dt * pff + (2.0 * Q[0, 0] if dt > 0 else 0.0))

    def correction(self, t_local_s: float) -> list[float]:
        """Broadcast clock correction at local time ``t_s``: ``[t_ref, theta, f, P_tt, P_tf, P_ff]``, the
        offset against (ensemble) network time."""
        if self.exact:
            return [float(t_local_s), 0.0, 0.0, 0.0, 0.0, 0.0]
        self.predict(self.network_time(t_local_s))
        a, f, ptt, ptf, pff = self._ens(self.id)
        dt = self.network_time(t_local_s) - self.T_s  # 0 unless t_local_s lies in the filter's past
        return [float(t_local_s), float(a + f * dt), float(f),
                float(ptt + 2 * dt * ptf + dt * dt * pff + self._scale_var_s2
                      + (0.0 if self._rooted else UNROOTED_SD_S**2)), float(ptf + dt * pff), float(pff)]

    def ensemble_offset_at(self, t_local_s: float) -> tuple[float, float]:
        """Estimated own offset against (ensemble) network time at local ``t_local_s`` and its variance
        (predicted; the filter unchanged), s and s^2."""
        if self.exact:
            return 0.0, 0.0
        e, f, ptt, ptf, pff = self._ens(self.id)
        qfac = sum(c * c for c in self._coeffs(self.id, self.scale.w).values())  # its offset wanders with qfac Q
        dt = self.network_time(t_local_s) - self.T_s
        var = ptt + 2 * dt * ptf + dt * dt * pff + (qfac * self._Q(dt)[0] if dt > 0 else 0.0)
        return float(e + f * dt), float(max(var, 0.0))

    # ------------------------------------------------------------------ ensemble network time
    def _coeffs(self, sid: int, weights: dict[int, float]) -> dict[int, float]:
        """Clock ``sid``'s offset against the ensemble as coefficients of the raw clocks."""
        c = {k: -w for k, w in weights.items()}
        c[sid] = c.get(sid, 0.0) + 1.0
        return c

    def _combo(self, coeffs: dict[int, float]) -> tuple[float, float, float, float, float]:
        """``sum c_k theta_k``, ``sum c_k f_k`` at ``T_s`` and their covariance ``(P_tt, P_tf, P_ff)``
        (station 1, the filter's reference, has ``theta = f = 0``): :meth:`_combo_dense` of the
        coefficients over every clock of the state."""
        cs = np.zeros(len(self.index))
        for k, c in coeffs.items():
            if k != 1:
                cs[self.index[k]] += c
        return self._combo_dense(_on_states(cs))

    def _combo_dense(self, V: np.ndarray, g: float | None = None) -> tuple[float, float, float, float, float]:
        """:meth:`_combo` of the coefficients ``c`` over every clock of the state, given as the two
        state-space rows ``V = [c (x) e_theta, c (x) e_f]`` (2n, 2) (:func:`_on_states`): dense, O(n^2).

        ``V^T x = [sum c theta, sum c f]``; ``V^T P0 V`` holds ``c^T B_tt c``, ``c^T B_tf c``, ``c^T B_ff c``
        over the blocks of ``P0``; through ``F`` over ``dt = T_s - T0``: ``P_ff = c^T B_ff c``,
        ``P_tf = c^T B_tf c + dt P_ff``, ``P_tt = c^T B_tt c + 2 dt c^T B_tf c + dt^2 P_ff``, plus ``Q(dt)``
        times ``c^T (I + 1 1^T) c = sum c^2 + (sum c)^2`` (each clock's own wander and network time's;
        ``g``: that value when the caller knows it and ``c != 0``)."""
        if g is None:
            cs = V[0::2, 0]
            if not np.count_nonzero(cs):
                return 0.0, 0.0, 0.0, 0.0, 0.0
            g = float(cs @ cs + np.add.reduce(cs) ** 2)  # (np.add.reduce: cs.sum() without its wrapper)
        th, f = (self.x @ V).tolist()
        (ctt, ctf), (_, ff) = (V.T @ self._P0 @ V).tolist()
        dt = self.T_s - self._T0
        if dt <= 0:
            return th, f, ctt, ctf, ff
        a, b, q = self._Q(dt)
        return th, f, ctt + 2.0 * dt * ctf + dt * dt * ff + g * a, ctf + dt * ff + g * b, ff + g * q

    def _members(self) -> tuple[dict[int, float], np.ndarray]:
        """The time scale's weights ``{clock: w}`` and ``-w`` over the state's clocks as the rows of
        :meth:`_combo_dense` (2n, 2) (station 1 has no state): the ensemble's coefficients in a clock's
        offset against it (:meth:`_coeffs`). Kept until the scale or the clocks change, with the
        coefficients ``-w`` (n,) as Python floats (``_members_c``)."""
        sc, n = self.scale, len(self.index)
        if self._members_of is not sc or len(self._members_neg) != 2 * n:
            w = sc.w
            neg = np.zeros(n)
            for k, c in w.items():
                if k != 1:
                    neg[self.index[k]] += -c
            self._members_of, self._members_w, self._members_neg = sc, w, _on_states(neg)
            self._members_c = neg.tolist()
        return self._members_w, self._members_neg

    def _ens(self, sid: int) -> tuple[float, float, float, float, float]:
        """Clock ``sid``'s offset and frequency against network time at ``T_s`` and their covariance
        ``(P_tt, P_tf, P_ff)``."""
        sc = self.scale
        V = self._members()[1].copy()  # sid's coefficients c (_coeffs) over the state's clocks
        c = list(self._members_c)
        if sid != 1:
            k = self.index[sid]
            V[2 * k, 0] += 1.0
            V[2 * k + 1, 1] += 1.0
            c[k] += 1.0
        # c^T (I + 1 1^T) c on floats (:meth:`_combo_dense`; c = 0: its zeros)
        th, f, tt, tf, ff = self._combo_dense(V, sum(ci * ci for ci in c) + sum(c) ** 2 if any(c) else None)
        return th - sc.a_s - sc.b * (self.T_s - sc.T_ref_s), f - sc.b, tt, tf, ff

    def on_peer_scale(self, src: int, t_tx_src_s: float, corr) -> None:
        """A peer's broadcast correction ``corr`` (its offset against *its* network time at its stamp
        ``t_tx_src_s``) against our estimate of the same clock against *our* network time: their
        difference is how far the two definitions are apart, ``N_src - N_me`` (both filters are, up
        to the navs they missed, the centralized one, so only the definitions differ). Collected for
        the steering at the next tick."""
        if self.exact or corr is None or src == self.id or (src != 1 and src not in self.index):
            return
        dT = t_tx_src_s - corr[0]
        th_peer = corr[1] + corr[2] * dT
        var_peer = corr[3] + 2 * dT * corr[4] + dT * dT * corr[5]
        # the peer's definition: agreed (0: its offset known to STEER_GATE_S), descending from the founders'
        # but not agreed yet (1: it carries UNAGREED_SD_S), or not descending from them (2: UNROOTED_SD_S),
        # used only while ours does not either
        tier = 0 if var_peer <= STEER_GATE_S**2 else 1 if var_peer <= UNAGREED_SD_S**2 + STEER_GATE_S**2 else 2
        if tier == 2 and (self._rooted or var_peer > UNROOTED_SD_S**2 + UNAGREED_SD_S**2 + STEER_GATE_S**2):
            return
        T, _ = self.peer_time(src, t_tx_src_s)
        e, f, ptt, ptf, pff = self._ens(src)
        dt = T - self.T_s
        v_me = ptt + 2 * dt * ptf + dt * dt * pff
        if v_me > STEER_GATE_S**2:
            return
        d = (e + f * dt) - th_peer
        r = f - corr[2] if pff + corr[5] <= STEER_RATE_GATE**2 else math.nan
        # an agreed definition moves by nanoseconds: a larger disagreement is not a steering input; one
        # not yet agreed may lie as far from the field's as the clocks' offsets over the members (a
        # founder powering on after the others defined time without it: milliseconds), all of which the
        # first steering adopts
        limit_s = UNAGREED_LIMIT_S if self._scale_var_s2 >= UNAGREED_SD_S**2 or not self._rooted else AGREED_LIMIT_S
        if math.isfinite(d) and abs(d) < limit_s:
            # the variance of d: our estimate of the clock against our definition and the peer's of the
            # same clock against its own, taken as large as ours (its broadcast variance also carries its
            # definition's last disagreement: what is measured here, not the noise of the measurement)
            self._disagree.append((d, r, tier, max(2.0 * v_me, 1e-30)))  # (0: one-clock definitions)

    def _steer(self) -> None:
        """Once per second of ``T``: move this station's definition toward its peers' (consensus)."""
        if not self._disagree:
            return
        # agreed peers' definitions first (a joiner takes the field's); none agreed yet (a cold start):
        # the founders steer on each other's; definitions that do not descend from the founders' last,
        # and only by a station whose own does not either (on_peer_scale)
        # a definition that does not descend from the founders' takes one that does in full
        tier = min(x[2] for x in self._disagree)
        use = [x for x in self._disagree if x[2] == tier]
        self._disagree.clear()
        full = self._scale_var_s2 >= UNAGREED_SD_S**2 or (not self._rooted and tier < 2)
        self._rooted = self._rooted or tier < 2
        d, g, R = consensus_step(np.array([x[0] for x in use]), np.array([x[3] for x in use]))
        wr = [(1.0 / x[3], x[1]) for x in use if math.isfinite(x[1])]  # rates, with the phases' weights
        sc, T = self.scale, self.T_s
        # the phase at T moves by g d (consensus_step: the lazy weighted average of the neighbourhood's
        # definitions) and the rate by STEER_R times the weighted mean rate disagreement (T_ref_s kept: a
        # departure can still be dated back before this tick, _membership); the first steering adopts the
        # field's definition in full, phase and rate (g = 1: a joiner, which starts from its own, takes
        # the field's at once)
        if full:
            g = 1.0
        rate = sum(w * x for w, x in wr) / sum(w for w, _ in wr) if wr else 0.0
        db = (1.0 if full else STEER_R) * rate
        self.scale = TimeScale(sc.weights, a_s=sc.a_s + g * d - db * (T - sc.T_ref_s), b=sc.b + db,
                               T_ref_s=sc.T_ref_s, jump_s=0.0)
        # a definition is agreed once the field's phase and rate are both taken: adopted without the
        # rate (the clocks' rates not yet known to STEER_RATE_GATE) it stays unagreed and the next tick
        # adopts again (else the rate left over pulls it microseconds away); then its variance against
        # the neighbourhood's mean: what is left of the disagreement and the noise of the step
        self._scale_var_s2 = UNAGREED_SD_S**2 if full and not wr else ((1.0 - g) * d) ** 2 + g * g * R
        self.scale_log.append(self.scale)
        if len(self.scale_log) > SCALE_LOG_MAX:
            del self.scale_log[: len(self.scale_log) - SCALE_LOG_MAX]

    def _state(self, sid: int) -> tuple[float, float]:
        if sid == 1:
            return 0.0, 0.0
        k = self.index[sid]
        return float(self.x[2 * k]), float(self.x[2 * k + 1])

    def _change_states(self, gone: set[int], clocks: set[int]) -> tuple[float, dict[int, tuple[float, float]]]:
        """The time of a membership change and the ``(theta, f)`` at ``T_s`` of ``clocks`` for it.

        A departure dates back to the leaver's last exchange: its offset is taken where it was last
        measured, not extrapolated over LEAVE_S (the others' states are moved back to that time); a
        stepped clock's is its estimate from before the step, carried to ``T_s``."""
        T, stepped = self.T_s, self._stepped_T
        last = [stepped.get(s, self._heard_T.get(s, T)) for s in gone]
        T_c = max(last + [self.scale.T_ref_s]) if gone else T
        states = {s: self._state(s) for s in clocks}
        for s in gone & set(stepped):
            T0, th, f = self._stepped_state.pop(s)
            states[s] = (th + f * (T - T0), f)
            stepped.pop(s)  # (a stepped clock re-enters like any clock: once known again)
        return T_c, states

    def _membership(self) -> None:
        """Once per second of ``T``: members not heard for ``LEAVE_S`` leave, clocks known against the
        ensemble to ``ENTER_SD_S`` enter; on a change the weights are renormalized without a step
        (:func:`net.clock.ensemble_change`)."""
        if self.exact:
            return
        T = self.T_s
        heard = self._heard_T
        old = self.scale.w
        stepped = self._stepped_T
        alive = {s for s in old if s == self.id or (T - heard.get(s, -math.inf) <= LEAVE_S and s not in stepped)}
        if not alive:
            # none of our definition's clocks is heard (a station powered on after station 1 left, its
            # definition still station 1's clock): define it over the clocks we do hear, known against
            # each other, ours included; the first steering then adopts the field's definition
            me = self.index[self.id]  # (O(n): each heard clock against ours)
            alive = {self.id} | {s for s in self.index if s != self.id and T - heard.get(s, -math.inf) <= 1.5
                                 and self._var([me, self.index[s]], [1.0, -1.0], 0.0) <= ENTER_SD_S**2}
            if len(alive) < 2:
                return  # nobody to define time with yet: keep the scale (extrapolated)
            self._rooted = False  # a definition over the clocks around us, not continuous with the founders'
            self._scale_var_s2 = UNAGREED_SD_S**2
        w_alive = {s: 1.0 / len(alive) for s in alive}
        new = set(alive)
        for sid in [self.id, *self.index]:
            if sid in new or sid in stepped or (sid != self.id and T - heard.get(sid, -math.inf) > 1.5):
                continue
            c = self._combo(self._coeffs(sid, w_alive))
            if c[2] <= ENTER_SD_S**2 and c[4] <= ENTER_FREQ_SD**2:
                new.add(sid)
        if new == set(old):
            return
        T_c, states = self._change_states(set(old) - new, new | set(old))
        self.scale = ensemble_change(self.scale, {s: 1.0 / len(new) for s in new},
                                     {s: th - f * (T - T_c) for s, (th, f) in states.items()},
                                     {s: f for s, (_, f) in states.items()}, T_c)
        self.scale_log.append(self.scale)

    # ------------------------------------------------------------------ filter steps
    def predict(self, T_s: float) -> None:
        """Move every clock to network time ``T_s`` (no-op for the past: late inputs use ``H = [1, dt]``).
        The state moves (O(n)); the covariance follows lazily (class docstring)."""
        dt = T_s - self.T_s
        if dt <= 0 or not len(self.x):
            self.T_s = max(self.T_s, T_s)
            if not len(self.x):
                self._T0 = self.T_s
            return
        self.x[0::2] += dt * self.x[1::2]
        self.T_s = float(T_s)
        if math.floor(self.T_s) > self._tick_T:
            self._tick_T = math.floor(self.T_s)
            self._membership()
            self._steer()

    def _terms(self, T_s: float, terms: list[tuple[int, float]]) -> tuple[list[int], list[float], float]:
        """Sparse row of ``sum sign theta_sid(T_s)`` at the filter's time: block indices, signs and the
        ``dt = T_s - self.T_s`` (``<= 0``: late inputs use ``h = sign [1, dt]``); station 1 has no state."""
        ks, signs = [], []
        index = self.index
        for sid, sign in terms:
            if sid == 1:
                continue
            k = index.get(sid)
            ks.append(self._add(sid) if k is None else k)
            signs.append(sign)
        return ks, signs, T_s - self.T_s

    def _update(self, ks: list[int], signs: list[float], dt_h: float, z: float, r: float,
                gate: float = math.inf) -> float:
        """Scalar update ``z = h x + v``, ``var v = r``, ``h = sum_i s_i e_{k_i} (x) [1, dt_h]``; the NIS
        (above ``gate`` while both clocks are known to ``STEP_KNOWN_S``: returned, nothing updated)."""
        if self.T_s - self._T0 > self.rebase_s:
            self._rebase()
        PH, v = self._PH(ks, signs, dt_h)
        x = self.x
        hph, hx = 0.0, 0.0
        for k, sg in zip(ks, signs):
            hph += sg * (PH[2 * k] + dt_h * PH[2 * k + 1])
            hx += sg * (x.item(2 * k) + dt_h * x.item(2 * k + 1))
        S = hph + r
        nu = z - hx
        self._last_nu = nu
        if nu * nu > gate * S and hph <= STEP_KNOWN_S**2:
            return nu * nu / S
        g = nu / S
        x += np.array([p * g for p in PH])
        # Joseph form with the optimal gain K = P h / S: (I - K h) P (I - K h)^T + r K K^T = P - w w^T,
        # w = P h / sqrt(S); at the reference time T0: P0 - v v^T, v = F^{-1} w (exactly symmetric)
        g = 1.0 / math.sqrt(S)
        v = np.array([q * g for q in v])
        self._P0 -= v[:, None] * v  # np.outer(v, v)
        self.n_updates += 1
        return nu * nu / S

    def on_exchange(self, a: int, b: int, T_s: float, dtheta_s: float, t_var_s2: float = 0.0,
                    z_var_s2: float | None = None) -> float | None:
        """Two-way time transfer ``theta_a - theta_b = dtheta_s`` at network time ``T_s``; the NIS.
        ``z_var_s2``: the transfer's noise variance (a radio link's, from its SNR); None: ``(sigma_d / c)^2``.

        ``T_s`` is the network time of the exchange's midpoint on clock ``a`` (the initiator's local
        ``t_mid``) by this filter's estimate of clock ``a``, ``t_var_s2`` its variance. An error ``e`` in
        that time shifts the measurement by ``(f_a - f_b) e``: charged as ``E[(f_a - f_b)^2] t_var``
        only while it is below ``time_gate`` times the time-transfer variance (after the coarse sync:
        microseconds x ppm, ~1e-4 of it). The error is that of a clock estimate, common to every
        exchange placed with it and correlated with the state, not independent noise: an exchange
        placed by a clock still unknown to a millisecond (ms x ppm: ns, as large as the measurement)
        is kept on clock ``a``'s local time and placed again when that clock is known
        (``n_deferred``; within ``defer_s``, else dropped: ``n_untimed``). Returns None unless used."""
        if self.exact or (a == 1 and b == 1):
            return None
        nis = self._exchange(a, b, T_s, dtheta_s, t_var_s2, z_var_s2)
        if nis is None and self._defer(a, b, T_s, dtheta_s, z_var_s2):
            return None
        self._retry()
        return nis

    def _defer(self, a: int, b: int, T_s: float, dtheta_s: float, z_var_s2: float | None) -> bool:
        """An exchange whose time is too uncertain: kept on clock ``a``'s local time (True), or
        dropped (``n_untimed``) when ``a`` is not in the filter (placed by a broadcast correction)."""
        k = self.index.get(a)
        if k is None:  # placed by a broadcast correction we cannot re-evaluate
            self.n_untimed += 1
            return False
        # back to clock a's local time (the inverse of peer_time / network_time)
        t_loc = T_s + self.x[2 * k] + self.x[2 * k + 1] * (T_s - self.T_s)
        self._pending.append((a, b, float(t_loc), float(dtheta_s), float(T_s), z_var_s2))
        self.n_deferred += 1
        return True

    def _exchange(self, a: int, b: int, T_s: float, dtheta_s: float, t_var_s2: float,
                  z_var_s2: float | None = None) -> float | None:
        """The update of ``on_exchange``; None (nothing changed) if its time is too uncertain."""
        r = self._transfer_r(a, b, t_var_s2, z_var_s2)
        if r is None:
            return None
        self.predict(T_s)
        ks, signs, dt_h = self._terms(T_s, [(a, 1.0), (b, -1.0)])
        n_before = self.n_updates
        w = self._members()[0]  # steps are judged between members of the time scale (acquired clocks)
        nis = self._update(ks, signs, dt_h, dtheta_s, r, gate=self.step_nis if a in w and b in w else math.inf)
        if self.n_updates == n_before:  # refused: a step of a or b (whichever keeps failing with every partner)
            self.n_step_refused += 1
            for sid, other, jump in ((a, b, self._last_nu), (b, a, -self._last_nu)):
                seen = self._refused.setdefault(sid, [])
                seen.append((jump, other))
                del seen[:-STEP_N]
                if sid != 1 and len(seen) == STEP_N and _one_jump(seen):
                    self._reinit(sid)
            return nis
        for sid in (a, b):
            self._heard_T[sid] = max(self._heard_T.get(sid, -math.inf), T_s)
            self._refused.pop(sid, None)
        return nis

    def _transfer_r(self, a: int, b: int, t_var_s2: float, z_var_s2: float | None) -> float | None:
        """Variance of a time transfer ``theta_a - theta_b`` whose network time has variance ``t_var_s2``
        (s^2): its noise (``z_var_s2``, None: ``(sigma_d / c)^2``) plus ``E[(f_a - f_b)^2] t_var`` on the
        filter as it is; None if that term exceeds ``time_gate`` times the noise (:meth:`on_exchange`)."""
        r = self.var_z if z_var_s2 is None else float(z_var_s2)
        if t_var_s2 > 0:
            ef, vf, ks, sg = 0.0, 0.0, [], []
            for sid, g in ((a, 1.0), (b, -1.0)):
                k = self.index.get(sid)
                if sid == 1:
                    continue
                if k is None:
                    vf += self.model.freq_sigma**2  # not in the filter yet: its prior
                else:
                    ks.append(k)
                    sg.append(g)
            if ks:
                ef, v = self._freq_diff(ks, sg)
                vf += v
            r_t = (float(ef) ** 2 + float(vf)) * t_var_s2
            if r_t > self.time_gate * r:
                return None
            r += r_t
        return r

    def on_exchanges(self, items: list[tuple]) -> list[float | None]:
        """The time transfers of one slot (a nav's entries) at once: each item ``(a, b, T_s, dtheta_s,
        t_var_s2, z_var_s2)`` as the arguments of :meth:`on_exchange`; their NIS (None: not used).

        One batch update (:meth:`_batch`): the filter predicted to the latest of their times, the
        earlier ones as late rows ``h = [1, dt]`` (as :meth:`on_exchange` takes a late input; no process
        noise between exchanges of one slot, milliseconds apart), ``R`` diagonal, one Cholesky factor of
        the (m, m) innovation covariance. Per exchange as in the sequential form: the time gate (and
        deferral) on the filter before the batch, the step gate on each exchange's *sequential* NIS -
        the squared whitened innovations ``L^-1 nu`` of the batch are exactly those (``S = L L^T``: the
        innovation of exchange ``i`` given ``1..i-1`` over its variance ``L_ii^2``). A step refused, or a
        clock not in the filter yet (the first seconds), makes the slot sequential: :meth:`on_exchange`
        for each. One item: :meth:`on_exchange` itself. Equal to the sequential updates to rounding
        (``tests/stations/test_clock_batch.py``)."""
        if self.exact or len(items) < 2 or any(s != 1 and s not in self.index for it in items for s in it[:2]):
            return [self.on_exchange(*it) for it in items]
        out: list[float | None] = [None] * len(items)
        use = []  # (item index, a, b, T_s, dtheta_s, r)
        for i, (a, b, T_s, z, t_var, z_var) in enumerate(items):
            if a == 1 and b == 1:
                continue
            r = self._transfer_r(a, b, t_var, z_var)
            if r is None:
                self._defer(a, b, T_s, z, z_var)
            else:
                use.append((i, a, b, T_s, z, r))
        nis = self._batch(use) if use else []
        if nis is None:  # a step refused in the slot: the sequential form (after the same prediction)
            for i, *_ in use:
                out[i] = self.on_exchange(*items[i])
            return out
        for (i, *_), v in zip(use, nis):
            out[i] = v
        self._retry()
        return out

    def _batch(self, use: list[tuple[int, int, int, float, float, float]]) -> list[float] | None:
        """The batch update of :meth:`on_exchanges` (``use``: item index, a, b, T_s, dtheta_s, r); the
        sequential NIS of each, or None (the filter predicted, nothing updated) if the step gate
        refuses one.

        Row ``i`` is ``h_i = e_a (x) [1, dt_i] - e_b (x) [1, dt_i]`` (``dt_i`` from the filter's time
        ``T_s``; station 1 has no state). With ``F`` over ``dt = T_s - T0`` (:meth:`_rows`):
        ``V = H P(T_s) F^-T`` (m, n) from one product ``(H F) P0``; ``P(T_s) H^T = F V^T``, so
        ``S = (H F) V^T + R = L L^T``; ``[e, B] = L^-1 [nu, V]``; ``x += F B^T e`` and ``P0 -= B^T B``
        (at ``T_s``: ``P - K S K^T`` with the optimal gain ``K = P H^T S^-1``, the Joseph form's value)."""
        self.predict(max(u[3] for u in use))
        if self.T_s - self._T0 > self.rebase_s:
            self._rebase()
        w = self._members()[0]  # steps are judged between members of the time scale (acquired clocks)
        HF, V, nu = self._rows(use)
        m = len(use)
        S = HF @ V.T
        S = 0.5 * (S + S.T)
        r = [u[5] for u in use]
        S.flat[:: m + 1] += r
        # NumPy's LAPACK (SciPy's triangular solve starts OpenBLAS threads: milliseconds a call on a
        # loaded machine for this 8 x 19 system)
        L = _cholesky(S)
        Z = _solve(L, np.concatenate([np.array(nu)[:, None], V], axis=1))
        e = Z[:, 0].tolist()
        d = [v * v for v in L.diagonal().tolist()]  # each exchange's sequential S; minus r: its h P h^T
        for (_, a, b, _, _, _), ei, di, ri in zip(use, e, d, r):
            if ei * ei > (self.step_nis if a in w and b in w else math.inf) and di - ri <= STEP_KNOWN_S**2:
                return None
        B = Z[:, 1:]
        dx = Z[:, 0] @ B  # F^-1 P H^T S^-1 nu
        dx[0::2] += (self.T_s - self._T0) * dx[1::2]
        self.x += dx
        D = B.T @ B
        self._P0 -= 0.5 * (D + D.T)
        self.n_updates += m
        self._last_nu = e[-1] * math.sqrt(d[-1])
        for _, a, b, T_s, _, _ in use:
            for sid in (a, b):
                self._heard_T[sid] = max(self._heard_T.get(sid, -math.inf), T_s)
                self._refused.pop(sid, None)
        return [ei * ei for ei in e]

    def _rows(self, use: list[tuple[int, int, int, float, float, float]]
              ) -> tuple[np.ndarray, np.ndarray, list[float]]:
        """For :meth:`_batch`: ``H F`` (m, n), ``V = H P(T_s) F^-T`` (m, n) and the innovations (m) of the
        transfers ``theta_a - theta_b``. ``V = (H F) P0 + C``: network time's wander and each clock's own
        (``Q (x) (I + 1 1^T)``), row ``i``: ``(s_i + sum s_i) (x) (F^-1 Q [1, dt_i])`` (as :meth:`_PH`)."""
        idx, T_s = self.index, self.T_s
        dt = T_s - self._T0
        nc = len(self.x) // 2
        xs = self.x.tolist()
        qtt, qtf, qff = self._Q(dt) if dt > 0 else (0.0, 0.0, 0.0)
        hf, cg, nu = [], [], []
        # on Python floats (NumPy's per-call cost dominates at 9 clocks): the same elementwise values as
        # the arrays "inc" (each row's signs over the clocks), "F^T h" = [inc, inc (dt + dt_i)] and the
        # wander "(inc + sum inc) (x) F^-1 Q [1, dt_i]", so the products below are those of the array form
        for _, a, b, T, z, _ in use:
            dth = T - T_s
            dti = dt + dth
            gt, gf = qtt + dth * qtf, qtf + dth * qff  # Q [1, dt_i]; F^-1 of it: [gt - dt gf, gf]
            gi = gt - dt * gf
            terms = [(idx[sid], s) for sid, s in ((a, 1.0), (b, -1.0)) if sid != 1]
            tot = 0.0
            hx = 0.0
            for k, s in terms:
                tot += s
                hx += s * (xs[2 * k] + dth * xs[2 * k + 1])
            nu.append(z - hx)
            row = [0.0, 0.0 * dti] * nc
            crow = [tot * gi, tot * gf] * nc
            for k, s in terms:
                row[2 * k], row[2 * k + 1] = s, s * dti
                c = s + tot
                crow[2 * k], crow[2 * k + 1] = c * gi, c * gf
            hf.append(row)
            cg.append(crow)
        HF = np.array(hf)  # rows s [1, dt + dt_i] on the clocks: F^T h
        V = HF @ self._P0  # (P0 F^T h)^T: P0 is symmetric
        if dt > 0:
            V += np.array(cg)
        return HF, V, nu

    def _freq_diff(self, ks: list[int], signs: list[float]) -> tuple[float, float]:
        """Mean and variance of ``sum_i s_i f_{k_i}`` at ``T_s`` (block indices ``ks``, signs ``s``): the
        frequencies' block ``P_ff`` of :meth:`_cov` (``F`` leaves the frequencies, only ``Q`` adds)."""
        x, P0 = self.x, self._P0
        dt = self.T_s - self._T0
        q = self._Q(dt)[2] if dt > 0 else 0.0
        if len(ks) == 2 and signs[0] == 1.0 and signs[1] == -1.0 and ks[0] != ks[1]:
            # theta_a - theta_b (a time transfer): the loop below unrolled, the same operations
            i, j = 2 * ks[0] + 1, 2 * ks[1] + 1
            aa, ab, ba, bb = P0.item(i, i), P0.item(i, j), P0.item(j, i), P0.item(j, j)
            if dt > 0:
                aa, ab, ba, bb = aa + 2.0 * q, ab + 1.0 * q, ba + 1.0 * q, bb + 2.0 * q
            return (0 + x.item(i)) + -1.0 * x.item(j), (((0 + aa) + -1.0 * ab) + -1.0 * ba) + bb
        ef = vf = 0
        for ki, gi in zip(ks, signs):
            ef = ef + gi * x[2 * ki + 1]
            for kj, gj in zip(ks, signs):
                ff = P0.item(2 * ki + 1, 2 * kj + 1)
                if dt > 0:
                    ff = ff + (2.0 if ki == kj else 1.0) * q
                vf = vf + gi * gj * ff
        return ef, vf

    def _reinit(self, sid: int) -> None:
        """Forget clock ``sid``'s state (a step): decorrelated, class-prior phase and frequency variances
        about its current estimate; the exchanges that follow re-acquire it."""
        self._rebase()
        k = self.index[sid]
        J = [2 * k, 2 * k + 1]
        before = (self.T_s, *self._state(sid))  # the refused transfers left it as it was before the step
        self._P0[J, :] = 0.0
        self._P0[:, J] = 0.0
        self._P0[J[0], J[0]] = self.model.offset_sigma_s**2
        self._P0[J[1], J[1]] = self.model.freq_sigma**2
        self._refused.pop(sid, None)
        self.n_reinit += 1
        if sid != self.id and sid in self.scale.w:  # it leaves the time scale where it was last good
            self._stepped_T[sid] = self._heard_T.get(sid, self.T_s)
            self._stepped_state[sid] = before
            self._membership()

    def _retry(self, force: bool = False) -> None:
        """Place the deferred exchanges whose clock is now known well enough (late inputs); at most
        every 0.1 s of network time unless ``force``, one try per clock still unknown."""
        if not self._pending or (not force and self.T_s - self._retry_T < 0.1):
            return
        self._retry_T = self.T_s
        keep, unknown = [], set()
        for a, b, t_loc, z, T0, zv in self._pending:
            if a not in unknown:
                T, var = self.peer_time(a, t_loc)
                if self._exchange(a, b, T, z, var, zv) is not None:
                    continue
                unknown.add(a)
            if self.T_s - T0 <= self.defer_s:
                keep.append((a, b, t_loc, z, T0, zv))
            else:
                self.n_untimed += 1
        self._pending = keep

    def on_nav(self, src: int, t_rx_s: float, t_tx_src_s: float, corr) -> bool:
        """Coarse one-way timing of a nav from ``src`` (``t_tx`` on its clock, ``corr`` its broadcast
        correction) while ``theta_me - theta_src`` is unknown to more than the gate; True if used."""
        if self.exact or corr is None or src == self.id:
            return False
        if src == 1:
            self._ref_heard_local = max(self._ref_heard_local, t_rx_s)
        T = self.network_time(t_rx_s)
        if self._coarse_var_at(T, src) <= self.coarse_gate_s**2:  # the common case once synced
            # (the filter stays where it is: the next input predicts it); a station that never hears
            # station 1 knows its neighbours' clocks long before its own against station 1, the time
            # axis its exchanges are placed on: anchored by the peers (_anchor) meanwhile
            self._anchor(src, t_tx_src_s, corr, t_rx_s)
            return False
        self._anchor(src, t_tx_src_s, corr, t_rx_s)
        self.predict(T)
        ks, signs, dt_h = self._terms(T, [(self.id, 1.0), (src, -1.0)])
        if self._var(ks, signs, dt_h) <= self.coarse_gate_s**2:
            return False
        # t_rx - t_tx = d / c + theta_me - theta_src: the distance unknown (coarse variance)
        self._update(ks, signs, dt_h, t_rx_s - t_tx_src_s, self.coarse_var)
        self.n_coarse += 1
        self._retry()
        return True

    def _anchor(self, src: int, t_tx_src_s: float, corr, t_rx_s: float) -> None:
        """Station 1 silent (not heard for ``LEAVE_S``, nor since we started ``LEAVE_S`` ago) and our
        clock unknown: nothing measures the filter's coordinate clock any more, so only offset
        differences are observable and a station powering on could never know the field's time. The
        peer's broadcast offset against the ensemble, ``theta_src = corr`` (the field keeps the
        ensemble continuous with the coordinate clock it was started from), is then used as an
        absolute measurement of that clock, with variance ``var(corr) + ANCHOR_SD_S^2``; the coarse
        timing of the same nav then gives ours."""
        if (src == 1 or t_rx_s - max(self._ref_heard_local, self._t0_local) <= LEAVE_S
                or self._own()[2] <= self.coarse_gate_s**2):
            return
        th, var = predict_correction(corr, t_tx_src_s, self.model)
        T = t_tx_src_s - th  # the nav's transmit time in network time, by the sender's own correction
        self.predict(T)
        ks, signs, dt_h = self._terms(T, [(src, 1.0)])
        if self._var(ks, signs, dt_h) <= var + ANCHOR_SD_S**2:
            return  # that clock is already known as well as the anchor would tell
        self._update(ks, signs, dt_h, th, var + ANCHOR_SD_S**2)
        self.n_anchor += 1

    def _coarse_var_at(self, T_s: float, src: int) -> float:
        """Variance of ``theta_me - theta_src`` predicted to network time ``T_s`` without moving the
        filter (only the two clocks' 2x2 blocks: O(1) instead of a full predict). The wander common to
        every offset cancels in the difference (not against the reference, station 1); each
        non-reference clock adds its own ``Q_tt``."""
        dt = max(T_s - self.T_s, 0.0)
        ks, signs = [], []
        for sid, sign in ((self.id, 1.0), (src, -1.0)):
            k = self.index.get(sid)
            if sid == 1:
                continue
            if k is None:
                return float("inf")  # not in the filter yet: unknown
            ks.append(k)
            signs.append(sign)
        if not ks:
            return 0.0
        var = self._var(ks, signs, dt)
        if dt > 0:  # each clock's own wander, plus the common one where it does not cancel
            var += (len(ks) + sum(signs) ** 2) * self._Q(dt)[0]
        return var

    def peer_times(self, sid: int, ts_peer_s: list[float], corr=None) -> list[tuple[float, float]]:
        """:meth:`peer_time` at several local times of station ``sid`` (a nav's exchanges): its clock's
        state and 2x2 covariance block read once (:meth:`peer_time` of a clock in the filter is this at one time)."""
        k = self.index.get(sid)
        if k is None:
            return [self.peer_time(sid, t, corr) for t in ts_peer_s]
        a, f, T_s = self.x.item(2 * k), self.x.item(2 * k + 1), float(self.T_s)
        ptt, ptf, _, pff = (float(v) for v in self._cov(k, k))
        out = []
        for t in ts_peer_s:
            T = (float(t) - a + f * T_s) / (1.0 + f)
            dt = T - T_s
            out.append((T, max(ptt + 2 * dt * ptf + dt * dt * pff, 0.0)))
        return out

    def peer_time(self, sid: int, t_peer_s: float, corr=None) -> tuple[float, float]:
        """Network time at station ``sid``'s local time ``t_peer_s`` and its variance, from this filter's
        own (prior) estimate of that clock; a station not in the filter yet: from its broadcast."""
        if sid == 1:
            return float(t_peer_s), 0.0
        k = self.index.get(sid)
        if k is None:
            if corr is None:
                return float(t_peer_s), self.model.offset_sigma_s**2
            th, var = predict_correction(corr, t_peer_s, self.model)
            return t_peer_s - th, var
        return self.peer_times(sid, [t_peer_s])[0]


