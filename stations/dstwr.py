"""One poll, every peer answers (protocol v2, issue 31; not yet the running protocol): pure arithmetic
of asymmetric double-sided two-way ranging (DS-TWR) between one poller and N responders, the
two-way time transfer of each pair, and the reply sub-slot schedule.

No sockets, clocks or RNG: stamps in, times of flight, ranges and offsets out. Equation numbers
(V1)-(V7) are those of docs/protocol.md, "Protocol v2 (in progress, issue 31)".

Stamps (each on the clock of the station that takes it; local seconds)::

    poller A      T1 poll sent                 T4_k reply k received    T5 final sent
    responder k   T2_k poll received  T3_k reply k sent                 T6_k final received

Shapes: the poller's own stamps (``T1``, ``T5``, its frequency) have a batch shape ``B`` (``()`` for
one exchange); everything per responder has shape ``B + (N,)``; results have shape ``B + (N,)``. A
missing stamp (NaN) gives a NaN result for that responder only.

Clocks: ``t_local = (1 + f) t_true + offset`` (``f`` the fractional frequency, as
:class:`net.channel.Clock` ``drift``). A duration measured on a clock is divided by ``1 + f`` to be
in true seconds; pass the frequencies the network clock filter estimates, or 0 (the default) for
raw durations. Precision: float64 stamps of magnitude ``S`` seconds resolve ``S * 2.2e-16`` s
(``6.7e-8 m`` per second of magnitude), so keep stamps relative to a recent epoch (the slot start)
where sub-micrometre ranges matter.
"""

from __future__ import annotations

import numpy as np

from nav.geometry import SPEED_OF_LIGHT_M_S


def _scalars(*xs) -> bool:
    """All Python (or NumPy) float / int scalars: one exchange, computed on floats (the same
    operations in the same order as the array path, so the same values; NumPy's per-call cost is
    most of a station core's per-exchange time)."""
    for x in xs:
        if not isinstance(x, (float, int)):
            return False
    return True


def _poller(x) -> np.ndarray:
    """A poller quantity of batch shape ``B`` as ``B + (1,)``, to broadcast against ``B + (N,)``."""
    return np.asarray(x, float)[..., None]


def _durations(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, freq_poller, freq_responder):
    """Round trip ``Ra`` (poller) and reply delay ``Db`` (responder) in true seconds, eq. (V3)."""
    kp = 1.0 + _poller(freq_poller)
    kr = 1.0 + np.asarray(freq_responder, float)
    ra = (np.asarray(t_reply_rx_s, float) - _poller(t_poll_tx_s)) / kp
    db = (np.asarray(t_reply_tx_s, float) - np.asarray(t_poll_rx_s, float)) / kr
    return ra, db, kp, kr


def ds_twr_tof_s(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, t_final_tx_s, t_final_rx_s,
                 freq_poller=0.0, freq_responder=0.0) -> np.ndarray:
    """Asymmetric double-sided two-way time of flight per responder, s; shape ``B + (N,)``.

    With the durations of eq. (V3), each in true seconds (divided by ``1 + f`` of its clock)::

        Ra = T4 - T1,  Da = T5 - T4   (poller's clock)
        Db = T3 - T2,  Rb = T6 - T3   (responder's clock)

    the time of flight is (Decawave APS013, eq. (V4))::

        ToF = (Ra Rb - Da Db) / (Ra + Rb + Da + Db)

    exact for any clock offsets and any reply delays when the frequencies are the clocks' own
    (noiseless exchange; the propagation time is the same both ways). With raw durations (the
    frequencies unknown, 0) it is the true ToF scaled by the harmonic mean of the two clock rates,
    eq. (V5): ``ToF_raw = ToF * 2 ka kb / (ka + kb)`` with ``k = 1 + f`` - a relative error of
    about ``(fa + fb) / 2`` on the time of flight alone, independent of the reply delays.

    Parameters
    ----------
    t_poll_tx_s : ``B``, T1. t_poll_rx_s : ``B + (N,)``, T2. t_reply_tx_s : ``B + (N,)``, T3.
    t_reply_rx_s : ``B + (N,)``, T4. t_final_tx_s : ``B``, T5. t_final_rx_s : ``B + (N,)``, T6.
    freq_poller : ``B``, fractional frequency of the poller's clock. freq_responder : ``B + (N,)``.
    """
    ra, db, kp, kr = _durations(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, freq_poller, freq_responder)
    da = (_poller(t_final_tx_s) - np.asarray(t_reply_rx_s, float)) / kp
    rb = (np.asarray(t_final_rx_s, float) - np.asarray(t_reply_tx_s, float)) / kr
    return (ra * rb - da * db) / (ra + rb + da + db)


def ds_twr_range_m(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, t_final_tx_s, t_final_rx_s,
                   freq_poller=0.0, freq_responder=0.0) -> np.ndarray:
    """Range per responder, m: ``c`` times :func:`ds_twr_tof_s` (same arguments and shapes), eq. (V4)."""
    stamps = (t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, t_final_tx_s, t_final_rx_s)
    if _scalars(*stamps, freq_poller, freq_responder):  # one exchange (the station core's final)
        t1, t2, t3, t4, t5, t6 = (float(t) for t in stamps)
        kp, kr = 1.0 + float(freq_poller), 1.0 + float(freq_responder)
        ra, db = (t4 - t1) / kp, (t3 - t2) / kr
        da, rb = (t5 - t4) / kp, (t6 - t3) / kr
        return np.float64(SPEED_OF_LIGHT_M_S * ((ra * rb - da * db) / (ra + rb + da + db)))
    return SPEED_OF_LIGHT_M_S * ds_twr_tof_s(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s,
                                             t_final_tx_s, t_final_rx_s, freq_poller, freq_responder)


def sym_twr_range_m(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, t_final_tx_s, t_final_rx_s,
                    freq_poller=0.0, freq_responder=0.0) -> np.ndarray:
    """The exchange's two single-sided ranges averaged, m; same arguments and shapes as
    :func:`ds_twr_tof_s`, eq. (V4b)::

        range = c (Ra - Db + Rb - Da) / 4

    the mean of the poller's single-sided range ``(Ra - Db) / 2`` and the one the final closes on the
    responder's side, ``(Rb - Da) / 2``. In range units the poll, reply and final legs carry
    independent noise ``e1, e2, e3`` of variance ``2 sigma_d^2`` each (net/channel.py); this range's
    error is ``(e1 + 2 e2 + e3) / 4``, variance ``3/4 sigma_d^2`` - the exchange's bound
    (``nav.crlb.poll_exchange_counts``) - where the single-sided range has ``sigma_d^2`` and DS-TWR
    (V4) ``sigma_d^2 (1 + w^2 + (1 - w)^2) / 2``, ``w = Da / (Da + Db)`` (3/4 to 0.92 in seed000's
    plan). It needs the clocks' frequencies: an error ``dfa, dfb`` in them biases it by
    ``c (dfb - dfa) (Db - Da) / 4`` (half the single-sided range's ``c (dfb - dfa) Db / 2`` at most),
    where DS-TWR is first-order free of them (V5).
    """
    stamps = (t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, t_final_tx_s, t_final_rx_s)
    if _scalars(*stamps, freq_poller, freq_responder):  # one exchange (the station core's final)
        t1, t2, t3, t4, t5, t6 = (float(t) for t in stamps)
        kp, kr = 1.0 + float(freq_poller), 1.0 + float(freq_responder)
        return np.float64(0.25 * SPEED_OF_LIGHT_M_S * ((t4 - t1 - t5 + t4) / kp + (t6 - t3 - t3 + t2) / kr))
    ra, db, kp, kr = _durations(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, freq_poller, freq_responder)
    da = (_poller(t_final_tx_s) - np.asarray(t_reply_rx_s, float)) / kp
    rb = (np.asarray(t_final_rx_s, float) - np.asarray(t_reply_tx_s, float)) / kr
    return 0.25 * SPEED_OF_LIGHT_M_S * (ra - db + rb - da)


def ss_twr_tof_s(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s,
                 freq_poller=0.0, freq_responder=0.0) -> np.ndarray:
    """Single-sided two-way time of flight (what the addressed protocol measures), s; ``B + (N,)``.

    ``ToF_ss = (Ra - Db) / 2``, eq. (V6). With the clocks' own frequencies it is exact too; with
    raw durations its error is ``(ka - kb) Db / 2 + (ka - 1) ToF`` (true ``Db``): the rate
    difference acts on the whole reply delay, which for reply sub-slot ``k`` grows with ``k``.
    Shapes as :func:`ds_twr_tof_s`.
    """
    ra, db, _, _ = _durations(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s, freq_poller, freq_responder)
    return 0.5 * (ra - db)


def time_transfer_s(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s) -> tuple[np.ndarray, np.ndarray]:
    """Two-way time transfer of each pair: ``(dtheta_s, t_mid_s)``, both ``B + (N,)``.

    Eq. (V7)::

        dtheta = ((T4 - T3) - (T2 - T1)) / 2,    t_mid = (T1 + T4) / 2   (poller's clock)

    ``dtheta`` is the poller's clock minus the responder's (``theta = t_local - t_true``, the sign of
    the addressed protocol's nav entries) at the true midpoint of the poll and the reply - the
    instant the poller's clock reads ``t_mid``. For clocks linear in true time and equal propagation
    both ways it is exact at that instant, whatever the offsets and frequencies; taken as the offset
    at the poll instant instead it is off by ``(fa - fb) (T4 - T1) / 2`` to first order.
    """
    if _scalars(t_poll_tx_s, t_poll_rx_s, t_reply_tx_s, t_reply_rx_s):  # one exchange
        t1, t2, t3, t4 = float(t_poll_tx_s), float(t_poll_rx_s), float(t_reply_tx_s), float(t_reply_rx_s)
        return np.float64(0.5 * ((t4 - t3) - (t2 - t1))), np.float64(0.5 * (t1 + t4))
    t1, t4 = _poller(t_poll_tx_s), np.asarray(t_reply_rx_s, float)
    t2, t3 = np.asarray(t_poll_rx_s, float), np.asarray(t_reply_tx_s, float)
    dtheta = 0.5 * ((t4 - t3) - (t2 - t1))
    return dtheta, np.broadcast_to(0.5 * (t1 + t4), dtheta.shape).copy()


def reply_offset_s(index, turnaround_s: float, reply_spacing_s: float) -> np.ndarray:
    """Offset of reply sub-slot ``index`` from the poll, s, eq. (V1)::

        o_k = turnaround_s + k reply_spacing_s

    ``k`` is the responder's index in the poller's announced member list (0..N-1); the final takes
    sub-slot ``k = N``. A responder transmits reply ``k`` at ``T3_k = T2_k + o_k`` on its own clock (from
    its reception of the poll). ``index``: any integer array shape; the result has that shape.
    """
    if _scalars(index):
        return np.float64(turnaround_s + float(index) * reply_spacing_s)
    return turnaround_s + np.asarray(index, float) * reply_spacing_s


def in_reply_window(t_ref_s, t_rx_s, index, turnaround_s: float, reply_spacing_s: float,
                    max_range_m: float, guard_s: float = 0.0) -> np.ndarray:
    """Whether each received reply lies inside its own sub-slot window, eq. (V2); bool, broadcast shape.

    ``t_ref_s`` is the receiver's own stamp of the poll (its transmit stamp at the poller, its
    receive stamp anywhere else), ``t_rx_s`` its receive stamp of the reply, ``index`` the sender's
    index in the poll's member list (from the reply's ``src``, never from its arrival time). By the
    triangle inequality every receiver hears reply ``k`` at ``t_rx - t_ref`` in
    ``[o_k, o_k + 2 max_range_m / c]``; the window widens that by ``guard_s`` either side (clock-rate
    error ``|fa - fb| o_k``, timing noise, NLOS)::

        o_k - guard_s <= t_rx - t_ref <= o_k + 2 max_range_m / c + guard_s

    A reply outside its window is dropped (and counted by the caller), never given to another
    member whose window it happens to fall in. The final checks the same way with ``index = N``.
    """
    o = reply_offset_s(index, turnaround_s, reply_spacing_s)
    if _scalars(t_ref_s, t_rx_s, index):  # one reply: a Python bool
        dt = float(t_rx_s) - float(t_ref_s)
        return o - guard_s <= dt <= o + 2.0 * max_range_m / SPEED_OF_LIGHT_M_S + guard_s
    dt = np.asarray(t_rx_s, float) - np.asarray(t_ref_s, float)
    return (dt >= o - guard_s) & (dt <= o + 2.0 * max_range_m / SPEED_OF_LIGHT_M_S + guard_s)
