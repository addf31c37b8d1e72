"""Station-side integrity monitoring of peers (pure; no I/O, no RNG).

Each station tests every peer once per own cycle: is the link's recent ranging consistent with our
own estimate and the peer's broadcast estimate, given both covariances?

For peer ``j``, with the ranges ``d_k`` of the link measured (by either end) in the last
``window_s`` seconds (at least ``min_ranges`` of them), after a within-link consensus gate, two
statistics and the larger counts:

    T_j = (dbar - |c - c_j|)^2 / (sigma_d^2 / n + u^T (P + C_j) u),     u = (c - c_j) / |c - c_j|,

with ``dbar, n`` over (1) the window's line-of-sight cluster (its lowest densest cluster of ranges,
``estimators.los_cluster``: NLOS only lengthens a range; ranges within ``gate * sigma_d`` of it) when
at least two ranges agree there, and (2) the cluster of the newest range (ranges within
``gate * sigma_d / 2`` of a centre moved from that range to the mode of the ranges around it,
:func:`newest_mode`, ``n`` discounted for that cut) when it holds at least two: a fault's onset (a range bias) is a step
that the LOS cluster ignores until it outnumbers the older ranges, while NLOS excesses are spread
(exponential) and rarely agree. A window where no two ranges agree is inconclusive. Each statistic
is chi-square with 1 degree of freedom when both estimates and the ranges are what they claim
(the range noise, our error and the peer's error are independent and Gaussian); the larger of two
alarms at most twice as often as one. A peer whose
``T_j`` exceeds the ``1 - p_fa`` quantile in ``fail_to_exclude`` consecutive tests is *excluded*
(the survey estimator stops using it); an excluded peer whose ``T_j`` stays below the ``1 - readmit_p``
quantile (hysteresis: a faulty station's estimate partly absorbs its fault, so merely passing is not
enough) in ``pass_to_readmit`` consecutive tests is *re-admitted*. Each decision is announced as an
``integrity`` message. When more than half of the peers tested fail at once, the common factor is this station itself (a biased antenna, a
jumped clock): it excludes nobody new (``self_suspect``).

**Quorum.** Each station announces its own exclusions in its nav (``excluded``). A test sees a fault
only through its own links: a lying peer whose false position lies across our line of sight to it
leaves our ranges consistent while its bounded pull still drags our solve (``larns bench integrity
--recovery``: seed 31, one station excluded the liar 53 s after its neighbours). So a peer is also
excluded while at least ``quorum_min`` (2) and more than half of the live announcers other than
itself (those we have not excluded ourselves, heard within ``window_s``) announce it; the exclusion
lapses when the quorum does. Only own exclusions are announced (an adopted one would hold itself up),
and one insider's announcements can exclude nobody. Quorum decisions are ``integrity`` messages with
``dof = 0`` (``statistic``: votes, ``threshold``: votes needed).

Both estimates were partly built from this very link, which makes the residual smaller than the
formula says, and the survey's covariance is conservative (NEES below its band): on clean data the
observed false-alarm rate is at or below ``p_fa`` (measured in ``tests/stations/test_integrity.py`` and by
``larns bench integrity``).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.special import chdtri  # chi-square inverse survival (scipy.stats costs ~0.5 s of start-up)

from net.radio import range_var_m2

from .estimators import los_cluster


@dataclass
class PeerTest:
    ranges: deque = field(default_factory=deque)  # (t_s, range_m)
    fails: int = 0
    passes: int = 0
    excluded: bool = False
    statistic: float = 0.0
    n_tests: int = 0
    n_alarms: int = 0
    n_in: int = 0  # ranges ever appended: with len(ranges), the key of the window's content
    window_key: tuple[int, int] | None = None  # cache of the window's clusters (StationIntegrity._clusters)
    window_sets: list = field(default_factory=list)


def _skipped_mean_factor(c: float) -> float:
    """Variance of the mean of a normal sample's values within ``c`` sigma of their own mean (the
    fixed point of :func:`newest_mode`), per value kept, in units of ``sigma^2 / n_kept``: the
    M-estimator's ``E[psi^2] / E[psi']^2`` with ``psi(x) = x 1[|x| <= c]`` is
    ``1 / (P - 2 c phi(c))`` per value drawn, ``P = 2 Phi(c) - 1`` of them kept."""
    phi = math.exp(-0.5 * c * c) / math.sqrt(2.0 * math.pi)
    p = math.erf(c / math.sqrt(2.0))
    return p / (p - 2.0 * c * phi)


def _floats(a):
    """An array (3,) or (3, 3) as (nested) lists of Python floats; a list or tuple as it is (indexed alike)."""
    return a.tolist() if isinstance(a, np.ndarray) else a


def newest_mode(d: np.ndarray, half_width_m: float, factor: float, max_iter: int = 20) -> tuple[float, float] | None:
    """The cluster of the newest range ``d[-1]`` of a link's window ``d`` (k,): the ranges within
    ``half_width_m`` of a centre moved from the newest range to the mean of the ranges around it
    until it stays (mean shift to the mode of the window's ranges near the newest one). Returns
    ``(mean, n_eff)`` with ``n_eff`` the count divided by ``factor`` (:func:`_skipped_mean_factor` of the
    half-width in sigmas: a mean of values kept within 2 sigma of itself has variance
    ``1.29 sigma^2 / n``), or None below two ranges.

    Centred on the newest range itself the cluster's mean is a truncated sample's, biased towards
    that range's own noise (by about 0.3 sigma for a 1-sigma range), which ``sigma^2 / n`` over the
    hundreds of ranges a 25 Hz link holds reads as a fault (seed001: 15-28 % of clean tests
    alarmed); at the mode the cut is symmetric. A step (a fault's onset) larger than the width is a
    mode of its own, which the newest ranges find."""
    c = float(d[-1])
    sel = d[np.abs(d - c) <= half_width_m]
    for _ in range(max_iter):
        c_new = _mean(sel)
        if c_new == c:
            break
        c = c_new
        sel = d[np.abs(d - c) <= half_width_m]
        if sel.size < 2:
            return None
    if sel.size < 2:
        return None
    return _mean(sel), sel.size / factor


def _mean(v: np.ndarray) -> float:
    """``v.mean()`` of a non-empty (k,) array: the same pairwise sum over the count, without the wrapper."""
    return float(np.add.reduce(v)) / v.size


class StationIntegrity:
    """Chi-square consistency test of each peer, exclusion and re-admission (see module docstring)."""

    def __init__(self, station_id: int, sigma_d_m: float, *, p_fa: float = 1e-4, window_s: float = 20.0,
                 fail_to_exclude: int = 2, pass_to_readmit: int = 10, readmit_p: float = 0.1, gate: float = 4.0,
                 min_ranges: int = 3, quorum_min: int = 2, radio=None):
        self.id = station_id
        self.quorum_min = int(quorum_min)
        # announcer -> (local time heard, the peers it has excluded itself); admitted senders only
        self.announced: dict[int, tuple[float, frozenset[int]]] = {}
        self.adopted: set[int] = set()  # peers excluded by the quorum (module docstring)
        self.sigma_d_m = float(sigma_d_m)
        # the scenario's [radio] (net/radio.py): each link's range noise from its SNR at the estimated
        # geometry (range_var_m2); None: sigma_d on every link
        self.radio = radio
        self.p_fa = float(p_fa)
        self.threshold = float(chdtri(1, p_fa))
        self.readmit_threshold = float(chdtri(1, readmit_p))  # hysteresis: re-admit on clear passes
        self.window_s = float(window_s)
        self.fail_to_exclude = int(fail_to_exclude)
        self.pass_to_readmit = int(pass_to_readmit)
        self.gate = float(gate)
        self.newest_factor = _skipped_mean_factor(0.5 * self.gate)
        self.min_ranges = int(min_ranges)
        self.self_suspect = False  # most peers look inconsistent: the fault is probably ours
        self.peers: dict[int, PeerTest] = {}
        self.events: list[tuple[float, int, str, float]] = []  # (t_s, suspect, decision, statistic)

    @property
    def own_excluded(self) -> set[int]:
        """Peers this station's own test has excluded (what its nav announces)."""
        return {p for p, s in self.peers.items() if s.excluded}

    @property
    def excluded(self) -> set[int]:
        """Peers the survey leaves out: our own exclusions and the quorum's."""
        return self.own_excluded | self.adopted

    def on_announcement(self, src: int, excluded_ids, t_s: float) -> None:
        """A peer's nav: the peers it has excluded itself (its ``excluded`` field; none: empty)."""
        if src != self.id:
            self.announced[int(src)] = (float(t_s), frozenset(int(i) for i in excluded_ids or ()))

    def quorum(self, t_s: float, live) -> list[dict]:
        """Adopt or drop quorum exclusions among the ``live`` peers at ``t_s`` (module docstring);
        returns the decisions taken now (``integrity`` message bodies, ``dof = 0``)."""
        own = self.own_excluded
        fresh = {a: ex for a, (t, ex) in self.announced.items()
                 if a in live and a not in own and t_s - t <= self.window_s}
        now = set()
        votes_of: dict[int, tuple[int, int]] = {}
        for j in set().union(*fresh.values()) if fresh else ():
            if j == self.id or j in own:
                continue
            voters = [ex for a, ex in fresh.items() if a != j]
            votes = sum(j in ex for ex in voters)
            need = max(self.quorum_min, len(voters) // 2 + 1)
            votes_of[j] = (votes, need)
            if votes >= need:
                now.add(j)
        out = []
        for j, decision in [(j, "exclude") for j in sorted(now - self.adopted)] + \
                           [(j, "readmit") for j in sorted(self.adopted - now - own)]:
            votes, need = votes_of.get(j, (0, self.quorum_min))
            self.events.append((float(t_s), j, decision, float(votes)))
            out.append({"t_s": float(t_s), "suspect": int(j), "statistic": float(votes), "threshold": float(need),
                        "dof": 0, "p_fa": self.p_fa, "decision": decision})
        self.adopted = now
        if out:
            ex = sorted(self.excluded)
            for m in out:
                m["excluded"] = ex
        return out

    def on_range(self, peer_id: int, range_m: float, t_s: float) -> None:
        st = self.peers.setdefault(peer_id, PeerTest())
        st.ranges.append((float(t_s), float(range_m)))
        st.n_in += 1

    def revise_range(self, peer_id: int, old_m: float, new_m: float) -> bool:
        """Replace the newest range of ``peer_id`` equal to ``old_m`` in the window by ``new_m`` (a better
        measurement of the same exchange, as the survey takes it: protocol v2's member V4b for the
        poller's single-sided range); False if the window holds none."""
        st = self.peers.get(peer_id)
        if st is None:
            return False
        for i in range(len(st.ranges) - 1, -1, -1):
            t, r = st.ranges[i]
            if r == old_m:
                st.ranges[i] = (t, float(new_m))
                st.window_key = None  # the window's content changed
                return True
        return False

    def _clusters(self, st: PeerTest, sigma_m: float) -> list[tuple[float, int]]:
        """(mean range, count) of the window's clusters that the test uses (module docstring): the
        line-of-sight cluster and the newest range's, ``sigma_m`` the link's range noise. Depends on the
        window's ranges only, which change once in a few tests (ranges only join at the end and leave
        at the start): cached."""
        key = (st.n_in, len(st.ranges), sigma_m)
        if st.window_key != key:
            d = np.array([r for _, r in st.ranges])
            g = self.gate * sigma_m
            centre, support = los_cluster(d, g)
            sets = [d[np.abs(d - centre) <= g]] if support >= 2 else []
            sets = [(_mean(x), len(x)) for x in sets]
            newest = newest_mode(d, 0.5 * g, self.newest_factor)  # the newest range's cluster (a step: fault onset)
            if newest is not None:
                sets.append(newest)
            st.window_key, st.window_sets = key, sets
        return st.window_sets

    def statistic(self, peer_id: int, t_s: float, pos_m, cov_m2, peer_pos_m, peer_cov_m2) -> float | None:
        """``T_j`` of peer ``peer_id`` at local time ``t_s``; None without a range in the window."""
        st = self.peers.get(peer_id)
        if st is None:
            return None
        while st.ranges and st.ranges[0][0] < t_s - self.window_s:
            st.ranges.popleft()
        if len(st.ranges) < self.min_ranges:  # one or two ranges cannot tell an NLOS one-off from a fault
            return None
        var = range_var_m2(pos_m, peer_pos_m, self.radio, self.sigma_d_m)
        sets = self._clusters(st, self.sigma_d_m if self.radio is None else float(np.sqrt(var)))
        if not sets:  # no two ranges of the window agree (NLOS one-offs): inconclusive
            return None
        # 3-vectors and 3 x 3 matrices as Python floats (NumPy's per-call cost dominates at this size)
        (a0, a1, a2), (b0, b1, b2) = _floats(pos_m), _floats(peer_pos_m)
        d0, d1, d2 = a0 - b0, a1 - b1, a2 - b2
        pred = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        if pred <= 0.0:
            return None
        u0, u1, u2 = d0 / pred, d1 / pred, d2 / pred
        pv = 0.0  # u^T (P + C_j) u
        for ui, ci, di in zip((u0, u1, u2), _floats(cov_m2), _floats(peer_cov_m2)):
            pv += ui * ((ci[0] + di[0]) * u0 + (ci[1] + di[1]) * u1 + (ci[2] + di[2]) * u2)
        return max(float((mean - pred) ** 2 / (var / n + pv)) for mean, n in sets)

    def evaluate(self, t_s: float, pos_m, cov_m2, peers: dict[int, tuple]) -> list[dict]:
        """Test every peer with a range in the window. ``peers``: {id: (pos_m (3,), cov_m2 (3, 3))}
        from their latest broadcasts. Returns the decisions taken now (``integrity`` message bodies)."""
        out = []
        stats = {}
        pos_m, cov_m2 = _floats(pos_m), _floats(cov_m2)  # (read by every peer's test)
        for pid, (ppos, pcov) in peers.items():
            T = self.statistic(pid, t_s, pos_m, cov_m2, ppos, pcov)
            if T is not None:
                stats[pid] = T
        # if most of the peers tested fail, the common factor is this station (its own antenna, clock
        # or fix): exclude nobody new this round
        n_fail = sum(T > self.threshold for T in stats.values())
        self.self_suspect = len(stats) >= 4 and n_fail > len(stats) / 2
        for pid, T in stats.items():
            st = self.peers[pid]
            st.statistic = T
            st.n_tests += 1
            if T > self.threshold:
                st.n_alarms += 1
                st.fails += 1
                st.passes = 0
            else:
                st.fails = 0
                st.passes = st.passes + 1 if T <= self.readmit_threshold or not st.excluded else 0
            decision = None
            if not st.excluded and st.fails >= self.fail_to_exclude and not self.self_suspect:
                st.excluded, decision = True, "exclude"
            elif st.excluded and st.passes >= self.pass_to_readmit:
                st.excluded, decision = False, "readmit"
            if decision:
                self.events.append((float(t_s), pid, decision, T))
                out.append({"t_s": float(t_s), "suspect": int(pid), "statistic": T, "threshold": self.threshold,
                            "dof": 1, "p_fa": self.p_fa, "decision": decision})
        if out:
            ex = sorted(self.excluded)
            for m in out:
                m["excluded"] = ex
        return out
