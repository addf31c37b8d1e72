"""Issue 31: the network clock filter takes a slot's time transfers as one batch update
(``ClockEstimator.on_exchanges``); it equals the sequential scalar updates and a textbook linear
Kalman filter on a linear problem with many measurements per slot."""

from __future__ import annotations

import math

import numpy as np
import pytest

from stations.clocksync import ClockEstimator, ClockModel

# the TCXO preset's noise; the prior of a clock after the coarse sync (a microsecond; 1 ms against the
# 1.7 ns of a transfer puts the first slot's sequential NIS at the mercy of cancellation, in either form)
TCXO = ClockModel(q_wf_s=1e-20, q_rw_per_s=3e-22, offset_sigma_s=1e-6, freq_sigma=2e-6)
N_ST = 10


class _TextbookKF:
    """Plain linear KF of clocks 2..N against clock 1: dense ``F``, ``Q (x) (I + 1 1^T)``, stacked ``H``,
    gain from a linear solve, Joseph form."""

    def __init__(self, n_clocks, model, T0):
        self.n = 2 * n_clocks
        self.model, self.T = model, T0
        self.x = np.zeros(self.n)
        self.P = np.diag(np.tile([model.offset_sigma_s**2, model.freq_sigma**2], n_clocks))

    def predict(self, T):
        dt = T - self.T
        if dt <= 0:
            return
        m, k = self.model, self.n // 2
        F = np.kron(np.eye(k), [[1.0, dt], [0.0, 1.0]])
        Q1 = np.array([[m.q_wf_s * dt + m.q_rw_per_s * dt**3 / 3, m.q_rw_per_s * dt**2 / 2],
                       [m.q_rw_per_s * dt**2 / 2, m.q_rw_per_s * dt]])
        self.x = F @ self.x
        self.P = F @ self.P @ F.T + np.kron(np.eye(k) + np.ones((k, k)), Q1)
        self.T = T

    def update(self, H, z, r):
        S = H @ self.P @ H.T + np.diag(r)
        K = np.linalg.solve(S, H @ self.P).T  # P H^T S^-1 (S, P symmetric)
        self.x = self.x + K @ (z - H @ self.x)
        A = np.eye(self.n) - K @ H
        self.P = A @ self.P @ A.T + K @ np.diag(r) @ K.T


def _row(n_clocks, a, b, dt_h):
    """``theta_a - theta_b`` at ``dt_h`` from the filter's time, over clocks 2..N (clock 1: no state)."""
    h = np.zeros(2 * n_clocks)
    for sid, s in ((a, 1.0), (b, -1.0)):
        if sid != 1:
            h[2 * (sid - 2)] += s
            h[2 * (sid - 2) + 1] += s * dt_h
    return h


def _filter(step_nis=math.inf):
    est = ClockEstimator(2, TCXO, 0.0, 0.5, step_nis=step_nis)
    for sid in range(3, N_ST + 1):
        est._add(sid)  # every clock in the filter from the start: the textbook KF's state order
    return est


def _slots(seed, n_slots=40, same_time=False):
    """A linear problem: true clocks (random-walk model), per 10 ms slot of a 1 s cycle a poller and
    every other station, one time transfer each (the poller's entries in its nav), noisy."""
    rng = np.random.default_rng(seed)
    th = rng.normal(0.0, 2e-6, N_ST + 1)
    f = rng.normal(0.0, 1e-7, N_ST + 1)
    th[1] = f[1] = 0.0
    var_z = (0.5 / 299792458.0) ** 2
    slots = []
    for c in range(n_slots):
        poller = 1 + c % N_ST
        t0 = 0.1 * c + 0.01 * (poller - 1)
        items = []
        for k, peer in enumerate(p for p in range(1, N_ST + 1) if p != poller):
            T = t0 + (0.0 if same_time else 0.001 + 0.0005 * k)
            z = (th[poller] + f[poller] * T) - (th[peer] + f[peer] * T) + rng.normal(0.0, math.sqrt(var_z))
            zv = var_z * rng.uniform(0.5, 2.0)  # per-link noise (a radio link's)
            items.append((poller, peer, T, z, 0.0, zv))
        slots.append(items)
    return slots


@pytest.mark.parametrize("seed", range(4))
def test_clock_filter_batch_equals_sequential_and_a_textbook_kf(seed):
    """The clock filter equals a linear KF on a linear problem with many measurements per slot: the
    batch update (one per slot, 9 transfers) equals the scalar updates one by one (after the same
    prediction to the slot's latest time) and a plain dense linear KF, to rounding; the NIS each
    batch returns are the sequential ones."""
    batch, seq = _filter(), _filter()
    kf = _TextbookKF(N_ST - 1, TCXO, 0.0)
    for items in _slots(seed):
        T_b = max(it[2] for it in items)
        nb = batch.on_exchanges(items)
        seq.predict(T_b)
        ns = [seq.on_exchange(*it) for it in items]
        kf.predict(T_b)
        H = np.array([_row(N_ST - 1, a, b, T - T_b) for a, b, T, *_ in items])
        kf.update(H, np.array([it[3] for it in items]), np.array([it[5] for it in items]))
        np.testing.assert_allclose(nb, ns, rtol=1e-7, atol=1e-9)
    assert batch.n_updates == seq.n_updates == 9 * 40
    sd = np.sqrt(np.diag(kf.P))
    for est in (batch, seq):
        assert np.max(np.abs(est.x - kf.x) / sd) < 1e-6
        assert np.max(np.abs(est.P - kf.P) / np.outer(sd, sd)) < 1e-6
    # the filter converged (not a comparison of two filters that learnt nothing)
    assert np.sqrt(np.max(np.diag(batch.P)[0::2])) < 1e-9


def test_a_slot_at_one_time_is_the_sequential_filter_to_rounding():
    """All of a slot's transfers at one time: the batch is the old per-exchange path exactly in
    meaning (no late rows), equal to rounding."""
    batch, seq = _filter(), _filter()
    for items in _slots(7, same_time=True):
        batch.on_exchanges(items)
        for it in items:
            seq.on_exchange(*it)
    sd = np.sqrt(np.diag(seq.P))
    assert np.max(np.abs(batch.x - seq.x) / sd) < 1e-7
    assert np.max(np.abs(batch.P - seq.P) / np.outer(sd, sd)) < 1e-7


def test_a_step_in_the_slot_makes_it_sequential_with_the_same_gating():
    """A transfer refused by the step gate (a clock that jumped): the batch falls back to the scalar
    updates, so the refusal and its counters are the sequential filter's exactly."""
    slots = _slots(3, n_slots=150)  # 15 s: the clocks enter the time scale (steps are judged between members)
    batch, seq = _filter(step_nis=28.4), _filter(step_nis=28.4)
    for j, items in enumerate(slots):
        if j >= 130:  # clock 5 steps by 50 ns: every transfer with it is off by that
            items = [(a, b, T, z + 5e-8 * ((a == 5) - (b == 5)), tv, zv) for a, b, T, z, tv, zv in items]
        T_b = max(it[2] for it in items)
        batch.on_exchanges(items)
        seq.predict(T_b)
        for it in items:
            seq.on_exchange(*it)
    assert seq.n_step_refused > 0 and seq.n_reinit == 1 and 5 not in seq.scale.w  # it left the scale
    assert (batch.n_step_refused, batch.n_updates, batch.n_reinit) == (seq.n_step_refused, seq.n_updates,
                                                                       seq.n_reinit)
    sd = np.sqrt(np.diag(seq.P))
    assert np.max(np.abs(batch.x - seq.x) / sd) < 1e-6


def test_uncertain_times_are_deferred_per_exchange():
    """The time gate acts per transfer: one whose network time is too uncertain is deferred, the
    others of the slot are used."""
    est = _filter()
    items = _slots(1, n_slots=2)[1]  # station 2's slot (a transfer placed by clock 1 is never deferred)
    a, b, T, z, _, zv = items[3]
    items[3] = (a, b, T, z, 1e-6, zv)  # a millisecond-unknown time: (ppm x ms)^2 >> the transfer's variance
    out = est.on_exchanges(items)
    assert out[3] is None and est.n_deferred == 1
    # ... and placed by the retry that follows the batch: its clock (ours) is now known
    assert est.n_updates == len(items) and not est._pending
    assert all(v is not None for i, v in enumerate(out) if i != 3)
