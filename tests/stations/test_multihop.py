"""A multi-hop field without coarse fixes (issue 33 item 2): stations that hear none of the founders
locate themselves from neighbours already located, the founders' frame conventions hold, a peer
without a fix locates nobody, and the bound follows the links that exist."""

import numpy as np
import pytest

from larns.bench.survey import multihop_stats
from nav.crlb import _index, survey_crlb, survey_fim
from nav.geometry import frame_free_mask
from net.radio import link
from net.scenario import ScenarioError, load, order_founders_near
from stations.estimators import DistributedMap
from stations.sim import Simulator
from scenario_text import strip_toml

# a 12 km x 2.5 km strip, 14 stations on 10 m masts at -6 dBm (links to ~2.5-3 km), no coarse fix
STRIP = strip_toml("strip", "a 12 km strip of 14 stations, weak radio, no coarse fix", n=14, depth_m=2500.0,
                   cycle_s=0.2, tx_power_dbm=-6.0, sigma0_m=0.0)


@pytest.fixture(scope="module")
def strip(tmp_path_factory):
    path = tmp_path_factory.mktemp("mh") / "strip.toml"
    path.write_text(STRIP)
    scn = load(path)
    r = Simulator(scn).run(45.0, [45.0])
    return scn, r


def _links(scn):
    P = scn.pos_m
    A = np.asarray(link(P[:, None, :], P[None, :, :], scn.channel.radio).exists)
    return A & ~np.eye(len(P), dtype=bool)


def test_stations_beyond_the_founders_locate_themselves_from_located_neighbours(strip):
    scn, r = strip
    A = _links(scn)
    far = [i for i in range(3, len(scn.ids)) if not A[i, :3].any()]
    assert len(far) >= 3  # the field is multi-hop
    sig_h = np.sqrt(r.cov_m2[-1, :, 0, 0] + r.cov_m2[-1, :, 1, 1])
    located = sig_h < 500.0
    err_h = np.hypot(*(r.pos_m[-1, :, :2] - r.truth_m[:, :2]).T)
    # every station with at least three links is located (here: all but station 12, which has two)
    assert set(np.flatnonzero(~located)) == {i for i in range(len(scn.ids)) if A[i].sum() < 3}
    assert located[far].sum() >= len(far) - 1
    # ... where it is, within its own sigma
    assert np.all(err_h[located] <= 3.0 * sig_h[located] + 0.1), (err_h[located], sig_h[located])
    assert np.all(err_h[far][located[far]] < 5.0)


def test_the_survey_bench_reads_the_fields_graph(strip):
    scn, _ = strip
    mh = multihop_stats(scn)
    A = _links(scn)
    assert mh["degree_min"] == A.sum(axis=1).min() and mh["degree_max"] == A.sum(axis=1).max()
    assert mh["hear_no_founder_frac"] == pytest.approx(np.mean(~A[3:, :3].any(axis=1)))
    assert sum(mh["stations_per_hop"]) + mh["unreachable"] == len(scn.ids)
    assert mh["stations_per_hop"][0] == 3 and len(mh["stations_per_hop"]) >= 3


def _est(sid, sigma_d=0.5):
    return DistributedMap(sid, None, None, sigma_d)


def _range(est, peer, pos, truth, cov_sigma=0.1, rng=None):
    cov = np.eye(3) * cov_sigma**2
    d = float(np.linalg.norm(np.asarray(pos) - truth)) + (0.0 if rng is None else rng.normal(0, 0.3))
    est.on_range(peer, d, 0.0, True, np.asarray(pos, float), cov)


def test_a_peer_without_a_fix_locates_nobody():
    truth = np.array([900.0, 700.0, 5.0])
    peers = {4: [0.0, 0.0, 0.0], 5: [2000.0, 0.0, 3.0], 6: [500.0, 1800.0, -4.0], 7: [1500.0, 1500.0, 2.0]}
    est = _est(8)
    no_fix = np.diag([1000.0**2] * 3)
    for p, pos in peers.items():  # every peer still broadcasts its no-fix prior
        est.on_range(p, float(np.linalg.norm(np.asarray(pos) - truth)), 0.0, True, np.zeros(3), no_fix)
    assert not est.refresh() and not est.initialized
    rng = np.random.default_rng(3)
    for p in (4, 5, 6):  # three of them located: enough
        _range(est, p, peers[p], truth, rng=rng)
    assert est.refresh() and est.initialized
    sig = np.sqrt(np.diag(est.cov_m2))
    assert np.all(np.abs(est.pos_m[:2] - truth[:2]) < 3 * sig[:2] + 0.5)
    assert sig[2] <= est.no_fix_height_sigma_m  # height: the ground prior, not the no-fix 1 km


def test_the_founders_start_on_the_frames_sign_conventions():
    s2 = DistributedMap(2, None, None, 0.5)
    s2.on_range(1, 1500.0, 0.0, True, np.zeros(3), np.zeros((3, 3)))
    assert s2.refresh() and s2.pos_m[0] == pytest.approx(1500.0, abs=1e-6) and s2.pos_m[1:].tolist() == [0.0, 0.0]
    s3 = DistributedMap(3, None, None, 0.5)
    truth = np.array([400.0, 1200.0, 0.0])
    for p, pos in ((1, [0.0, 0.0, 0.0]), (2, [1500.0, 0.0, 0.0])):
        s3.on_range(p, float(np.linalg.norm(np.asarray(pos) - truth)), 0.0, True, np.asarray(pos), np.eye(3) * 0.01)
    assert s3.refresh()
    assert s3.pos_m[1] > 0.0 and np.allclose(s3.pos_m[:2], truth[:2], atol=0.5)  # +y, not its mirror


def test_a_degenerate_start_does_not_raise():
    s2 = DistributedMap(2, None, None, 0.5)
    s2.on_range(1, 0.0, 0.0, True, np.zeros(3), np.zeros((3, 3)))  # the start lands on the peer
    assert s2.refresh() is False and not s2.initialized


def test_founders_near_each_other_turn_counterclockwise():
    rng = np.random.default_rng(5)
    for _ in range(20):
        P = rng.uniform(0.0, 1.0, (60, 3)) * [30000.0, 20000.0, 80.0]
        order = order_founders_near(P, 3000.0)
        f = P[order[:4]]
        assert np.all(np.hypot(*(f[1:3, :2] - f[0, :2]).T) <= 3000.0)  # the founders hear each other
        assert np.hypot(*(f[2, :2] - f[1, :2])) <= 3000.0
        assert min(np.hypot(*(f[3, :2] - f[0, :2])), np.hypot(*(f[3, :2] - f[1, :2]))) <= 3000.0
        assert np.linalg.det(f[1:] - f[0]) > 0.0
        assert sorted(order.tolist()) == list(range(60))
    with pytest.raises(ScenarioError, match="founders_within_m"):
        order_founders_near(np.array([[0.0, 0, 0], [5000, 0, 0], [0, 5000, 0], [5000, 5000, 0]]), 1000.0)


def test_without_a_fix_the_founders_must_turn_counterclockwise(tmp_path):
    text = ('name = "cw"\ndescription = "x"\n[init]\nsigma0_m = 0.0\n'
            + "".join(f"[[stations]]\nid = {i}\npos_m = {p}\n" for i, p in
                      enumerate(([0.0, 0.0, 0.0], [1000.0, 0.0, 0.0], [300.0, -800.0, 0.0], [500.0, 400.0, 20.0]), 1)))
    path = tmp_path / "cw.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError, match=r"\[init\] sigma0_m: .*station 3 on the left"):
        load(path)
    path.write_text(text.replace("sigma0_m = 0.0", "sigma0_m = 10.0"))
    load(path)  # with a coarse fix the handedness is the fix's


def test_the_sparse_fisher_information_equals_the_per_link_sum():
    rng = np.random.default_rng(8)
    n = 12
    P = rng.uniform(0.0, 3000.0, (n, 3))
    free = frame_free_mask(n)
    idx = _index(free)
    for density in (1.0, 0.3):  # fully connected, then sparse
        C = rng.integers(1, 5, (n, n)) * (rng.random((n, n)) < density)
        np.fill_diagonal(C, 0)
        sig = rng.uniform(0.3, 1.2, (n, n))
        ref = np.zeros((int(free.sum()),) * 2)
        for i in range(n):
            ref[idx[i][free[i]], idx[i][free[i]]] += 1.0 / 10.0**2
        tot = C + C.T
        for i in range(n):
            for j in range(i + 1, n):
                if tot[i, j]:
                    u = (P[i] - P[j]) / np.linalg.norm(P[i] - P[j])
                    g = np.zeros(len(ref))
                    g[idx[i][free[i]]] += u[free[i]]
                    g[idx[j][free[j]]] -= u[free[j]]
                    ref += tot[i, j] / sig[i, j] ** 2 * np.outer(g, g)
        np.testing.assert_allclose(survey_fim(P, C, sig, free, 10.0), ref, rtol=1e-12, atol=1e-12)
    assert np.all(np.isfinite(survey_crlb(P, C, sig, free, 10.0)))


def test_the_common_part_of_the_peers_covariances_lies_below_each():
    from stations.estimators import common_lower_bound

    rng = np.random.default_rng(11)
    for _ in range(20):
        L = rng.normal(0.0, 1.0, (5, 3, 3))
        C = L @ np.swapaxes(L, 1, 2)
        X = common_lower_bound(C)
        assert np.linalg.eigvalsh(X).min() >= -1e-12
        # X <= C_j for every peer (up to the floor of 1e-9 of a trace on pinned coordinates)
        assert min(np.linalg.eigvalsh(Cj - X).min() / np.trace(Cj) for Cj in C) >= -1e-8
    C = np.stack([np.diag([4.0, 9.0, 100.0])] * 3)
    np.testing.assert_allclose(common_lower_bound(C), C[0], atol=1e-9)  # equal peers: all of it is common
    C[1] = np.diag([4.0, 0.0, 0.0])  # a founder pins y and z: they share x only
    np.testing.assert_allclose(common_lower_bound(C), np.diag([4.0, 0.0, 0.0]), atol=1e-6)
    C[2] = 0.0  # station 1 shares no error
    assert common_lower_bound(C) is None


def test_a_shift_all_peers_share_stays_in_the_reported_covariance():
    """Peers two hops out carry the same upstream error: all of them are off by one shift drawn from
    their (equal) covariance. The station's solve moves with them, and its covariance must say so:
    with the common part the mean NEES is about 3 (3 dof), per-link consider terms alone report the
    shift averaged away over the twelve links."""
    truth = np.array([1200.0, 900.0, 30.0])
    ang = np.arange(12) * np.pi / 6.0
    rad = np.where(np.arange(12) % 2, 2500.0, 1500.0)
    peers = np.column_stack([truth[0] + rad * np.cos(ang), truth[1] + rad * np.sin(ang),
                             np.random.default_rng(5).uniform(0.0, 60.0, 12)])
    Cp = np.diag([2.0**2, 2.0**2, 5.0**2])
    rng = np.random.default_rng(4)
    nees = {True: [], False: []}
    for _ in range(200):
        shift = rng.multivariate_normal(np.zeros(3), Cp)
        noise = rng.normal(0.0, 0.5, (12, 10))
        fix = truth + rng.normal(0.0, 10.0, 3)
        for common in (True, False):
            est = DistributedMap(9, fix, np.eye(3) * 100.0, 0.5, common_mode=common)
            for k in range(12):
                for r in range(10):
                    d = float(np.linalg.norm(truth - peers[k])) + noise[k, r]
                    est.on_range(k + 10, d, 0.0, True, peers[k] + shift, Cp)
            assert est.refresh()
            e = est.pos_m - truth
            nees[common].append(float(e @ np.linalg.solve(est.cov_m2, e)))
    assert 2.4 < np.mean(nees[True]) < 3.6  # honest (3 dof; measured 3.2)
    assert np.mean(nees[False]) > 5.0  # the shift averaged away: overconfident (measured 6.7)
