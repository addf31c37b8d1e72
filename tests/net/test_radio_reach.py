"""The simulator's shortcuts through the radio and the air give the same values as the long way:
net.radio.may_link (which pairs the simulator still asks), AirChannel.geometry (pairs kept by exact
position values) and the keyed draws' seed words."""

from dataclasses import dataclass

import numpy as np

from net.channel import AirChannel, Clock, _seed_words
from net.radio import RadioParams, link, may_link
from net.scenario import ChannelParams, load


@dataclass(frozen=True)
class RadioChannel(ChannelParams):
    """Channel parameters carrying a ``[radio]`` (the channel reads ``params.radio``)."""

    radio: RadioParams | None = None


def _field(rng, n: int, span_m: float) -> np.ndarray:
    pos = rng.uniform(-span_m, span_m, (n, 3))
    pos[:, 2] = rng.uniform(0.0, 120.0, n)
    return pos


def test_may_link_holds_every_link_the_radio_lets_exist():
    rng = np.random.default_rng(11)
    for power_dbm, height_m, two_ray in ((0.0, 10.0, True), (-20.0, 2.0, True), (30.0, 0.0, False)):
        params = RadioParams(tx_power_dbm=power_dbm, antenna_height_m=height_m, two_ray=two_ray)
        pos = _field(rng, 40, 15_000.0)
        reach = may_link(pos, params)
        exists = np.array([[bool(link(pos[i], pos[j], params).exists) for j in range(40)] for i in range(40)])
        assert not (exists & ~reach).any()
        assert exists.sum() < exists.size  # the fields are wide enough to have pairs out of reach
    assert may_link(pos, None).all()


def test_may_link_on_terrain_keeps_the_masked_pairs_to_the_exact_test():
    scn = load("hill")
    radio = scn.channel.radio
    reach = may_link(scn.pos_m, radio)
    n = len(scn.ids)
    exists = np.array([[bool(link(scn.pos_m[i], scn.pos_m[j], radio).exists) for j in range(n)] for i in range(n)])
    assert not (exists & ~reach).any()
    assert (reach & ~exists).any()  # terrain masks pairs the horizon and budget allow


def test_air_channel_geometry_kept_by_exact_positions_equals_a_fresh_channel():
    rng = np.random.default_rng(5)
    params = RadioChannel(sigma_d_m=0.5, radio=RadioParams(tx_power_dbm=0.0))
    kept = AirChannel(params, np.random.default_rng(0), (3, 2))
    pos = _field(rng, 12, 12_000.0)
    for _ in range(3):  # asked again and again: the kept answers
        for i in range(12):
            for j in range(12):
                fresh = AirChannel(params, np.random.default_rng(0), (3, 2))
                assert kept.geometry(pos[i], pos[j]) == fresh.geometry(pos[i], pos[j])
                t1 = kept.arrival_local_s(pos[i], 10.0 + i, pos[j], Clock(), tx_id=i + 1)
                t2 = fresh.arrival_local_s(pos[i], 10.0 + i, pos[j], Clock(), tx_id=i + 1)
                assert t1 == t2
    i, j = next((i, j) for i in range(12) for j in range(12) if i != j and kept.geometry(pos[i], pos[j]))
    moving = pos[i] + np.array([0.25, 0.0, 0.0])  # a moved end is computed, not taken from the other's
    fresh = AirChannel(params, np.random.default_rng(0), (3, 2))
    assert kept.geometry(moving, pos[j]) == fresh.geometry(moving, pos[j]) != kept.geometry(pos[i], pos[j])


def test_seed_words_give_the_generator_of_the_ints():
    rng = np.random.default_rng(2)
    for _ in range(500):
        values = [int(v) for v in rng.integers(0, 2**62, 4) >> rng.integers(0, 62, 4)]
        values[int(rng.integers(4))] = int(rng.choice([0, 2**32, 2**32 - 1, 2**40 + 7]))
        a, b = np.random.default_rng(values), np.random.default_rng(_seed_words(values))
        assert a.bit_generator.state == b.bit_generator.state
    assert _seed_words([1, -2]) is None
