"""The vehicle's channel under a scenario's ``[radio]`` (issue 33): a vehicle behind the horizon or the
link budget does not hear a station (the aircraft's channel model, :func:`net.radio.reception_sigma_m`)."""

from __future__ import annotations

from broadcast_support import nav_broadcast
from net.radio import link
from net.scenario import load


def test_the_vehicle_hears_only_the_linked_stations():
    from vehicle.core import VehicleCore

    # seed000's 2 km field with a transmitter so weak that the far stations drop out at ground level
    scn = load("seed000", radio={"tx_power_dbm": -5.0})
    core = VehicleCore(scn, "veh1", t0_s=0.0, imu_rate_hz=10.0)
    core.advance_to(1.0)
    outcomes = []
    for k, sid in enumerate(scn.ids):
        t = 1.0 + 0.01 * k
        msg, phy = nav_broadcast(scn, sid, t)
        got = core.measure(msg, phy)
        p_g, _ = core.truth(t - core.t0_s)
        exists = bool(link(scn.true_pos(sid), core.tie.to_network(p_g), scn.channel.radio).exists)
        assert (got is not None) == exists, sid
        outcomes.append(exists)
    assert any(outcomes) and not all(outcomes), outcomes
