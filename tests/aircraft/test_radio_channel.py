"""The user receivers' channel under a scenario's ``[radio]`` (issue 33): the aircraft (radio, inertial,
triad cores) hear exactly the links :func:`net.radio.reception_sigma_m` allows, with its
timing noise, and the navigators get that noise's variance (what a receiver knows from its SNR)."""

from __future__ import annotations

import numpy as np
import pytest

from broadcast_support import nav_broadcast
from aircraft.events import to_msgs
from net.radio import link, link_var_m2, reception_sigma_m
from net.scenario import load

# a 40 x 30 km field (seed003) heard by a weak transmitter: the aircraft hears the near stations only
RADIO = {"tx_power_dbm": 10.0}


@pytest.fixture(scope="module")
def radio_core():
    from aircraft.config import from_scenario
    from aircraft.radio_core import RadioAircraftCore

    scn = load("seed003", radio=RADIO)
    ac = from_scenario(scn)
    return scn, ac, RadioAircraftCore(ac, ("ekf-pr",), "ac1", np.random.default_rng(3), horizon_s=120.0)


def test_the_aircraft_hears_exactly_the_links_the_radio_allows(radio_core):
    scn, ac, core = radio_core
    heard, unheard = [], []
    for k, sid in enumerate(scn.ids):
        t = 10.0 + 0.01 * k
        msg, phy = nav_broadcast(scn, sid, t)
        p, _ = core.track.at(t)
        exists = bool(link(scn.true_pos(sid), p, ac.world.radio).exists)
        before = core.stats["no_link"]
        out = to_msgs(core.on_nav(msg, phy))
        if exists:
            heard.append(sid)
            assert core.stats["no_link"] == before and any(m["kind"] == "ac_truth" for m in out)
        else:
            unheard.append(sid)
            assert out == [] and core.stats["no_link"] == before + 1
    assert heard and unheard, (heard, unheard)  # the case has both
    # the journal holds only the heard stations, each with its link's variance in the station covariance
    entries = [e for e in core.journal.entries if e[0] == "m"]
    assert [e[2] for e in entries] == heard
    for e in entries:
        p, _ = core.track.at(e[1])
        s = reception_sigma_m(scn.true_pos(e[2]), p, ac.world.radio, ac.world.sigma_m)
        extra = np.asarray(e[4]) - np.eye(3) * 0.01
        assert np.allclose(extra, link_var_m2(s, ac.world.sigma_m) * np.eye(3), rtol=1e-6, atol=1e-12)


def test_the_aircraft_timing_noise_follows_the_links_snr(radio_core):
    scn, ac, core = radio_core
    t = 20.0
    p, _ = core.track.at(t)
    # the farthest station still heard: its noise is above the floor
    d = {sid: np.linalg.norm(scn.true_pos(sid) - p) for sid in scn.ids
         if link(scn.true_pos(sid), p, ac.world.radio).exists}
    sid = max(d, key=d.get)
    msg, phy = nav_broadcast(scn, sid, t)
    rho = np.array([core.measure(phy, msg)[1] for _ in range(4000)])
    s = reception_sigma_m(scn.true_pos(sid), core.measure(phy, msg)[2], ac.world.radio, ac.world.sigma_m)
    assert s > 1.2 * ac.world.sigma_m, (s, ac.world.sigma_m)
    # sample std of 4000 normal draws: relative standard error 1.1 %, tolerance 5 %
    assert np.std(rho) == pytest.approx(s, rel=0.05)


def test_inertial_and_triad_cores_drop_what_the_radio_does_not_carry():
    from aircraft.config import from_scenario
    from aircraft.ins_core import InsAircraftCore

    scn = load("seed003", radio=RADIO)
    ac = from_scenario(scn)
    core = InsAircraftCore(scn, ac, "ac1", np.random.default_rng(9), seed=5)
    outcomes = []
    for k, sid in enumerate(scn.ids):
        t = 5.0 + 0.01 * k
        msg, phy = nav_broadcast(scn, sid, t)
        p = core.truth_n(t)[0]
        exists = bool(link(scn.true_pos(sid), p, ac.world.radio).exists)
        got = core.measure(phy, msg)
        assert (got is not None) == exists
        if exists:
            want = reception_sigma_m(scn.true_pos(sid), p, ac.world.radio, ac.world.sigma_m)
            assert got[2] == pytest.approx(want, rel=1e-6)
        outcomes.append(exists)
    assert any(outcomes) and not all(outcomes)
