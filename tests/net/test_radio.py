"""net/radio.py: horizon, link budget, timing CRLB; net/channel.py applying them to receptions."""

from dataclasses import dataclass, replace

import numpy as np
import pytest

from net.channel import AirChannel, Clock
from net.radio import (RadioParams, horizon_m, link, link_var_m2, max_range_m, parse, path_loss_db,
                       reception_sigma_m)
from net.scenario import ChannelParams, ScenarioError

C = 299_792_458.0


@dataclass(frozen=True)
class RadioChannel(ChannelParams):
    """Channel parameters carrying a ``[radio]`` (the channel reads ``params.radio``)."""

    radio: RadioParams | None = None


def test_horizon_of_two_10_m_antennas_on_a_4_3_earth():
    # d = 2 sqrt(2 (4/3) 6371 km 10 m) = 26.07 km (the figure the large-field issue quotes, ~26 km)
    assert horizon_m(10.0, 10.0) == pytest.approx(2 * np.sqrt(2 * 4 / 3 * 6_371_000.0 * 10.0))
    assert horizon_m(10.0, 10.0) == pytest.approx(26_069, abs=1)
    # a true-Earth horizon (k = 1) is shorter; an aircraft at 1 km sees far beyond
    assert horizon_m(10.0, 10.0, 1.0) < horizon_m(10.0, 10.0)
    assert horizon_m(1010.0, 10.0) > 140_000


def test_path_loss_free_space_then_two_ray_and_never_decreasing():
    p = RadioParams()
    # free space at 1 km, 1 GHz: 20 log10(4 pi 1000 / 0.29979) = 92.44 dB
    assert path_loss_db(1000.0, 10.0, 10.0, replace(p, two_ray=False)) == pytest.approx(92.44, abs=0.01)
    d = np.linspace(10.0, 30_000.0, 3000)
    loss = path_loss_db(d, 10.0, 10.0, p)
    assert np.all(np.diff(loss) >= 0)
    crossover = 4 * np.pi * 10.0 * 10.0 / p.wavelength_m
    far = d > 2 * crossover
    # beyond the crossover: 40 dB per decade (plane Earth)
    assert np.allclose(loss[far], 40 * np.log10(d[far]) - 20 * np.log10(100.0))


def test_timing_crlb_follows_the_snr():
    p = RadioParams()
    near, far = link([0, 0, 0], [5_000.0, 0, 0], p), link([0, 0, 0], [20_000.0, 0, 0], p)
    beta = p.bandwidth_hz / np.sqrt(12)
    for lk in (near, far):
        snr = 10 ** (lk.snr_db / 10)
        assert lk.sigma_crlb_s == pytest.approx(1 / (2 * np.pi * beta * np.sqrt(2 * snr)))
    # 40 dB per decade beyond the two-ray crossover (4.2 km): sigma ~ d^2, 16x from 5 km to 20 km
    assert far.sigma_crlb_s / near.sigma_crlb_s == pytest.approx(16.0, rel=1e-6)
    assert near.exists and far.exists


def test_links_end_at_the_horizon_or_the_link_budget():
    p = RadioParams()
    h = horizon_m(10.0, 10.0)
    assert link([0, 0, 0], [h - 10.0, 0, 0], p).exists
    assert not link([0, 0, 0], [h + 10.0, 0, 0], p).exists
    weak = replace(p, tx_power_dbm=0.0)  # 30 dB less: the SNR ends the link first
    d_max = max_range_m(weak, 10.0, 10.0)
    assert d_max < h
    assert link([0, 0, 0], [d_max * 0.99, 0, 0], weak).exists
    assert not link([0, 0, 0], [d_max * 1.01, 0, 0], weak).exists
    # vectorized over leading axes
    many = link(np.zeros((4, 3)), np.array([[1e3, 0, 0], [1e4, 0, 0], [3e4, 0, 0], [2e4, 0, 0]]), p)
    assert many.exists.tolist() == [True, True, False, True]
    assert np.isinf(many.sigma_crlb_s[2])


def _errors_m(air: AirChannel, d_m: float, n: int) -> np.ndarray:
    clock = Clock()
    out = []
    for k in range(n):
        t = air.arrival_local_s(np.zeros(3), k * 1e-3, np.array([d_m, 0.0, 0.0]), clock, tx_id=2)
        out.append((t - k * 1e-3 - d_m / C) * C)
    return np.asarray(out)


def test_the_channel_applies_the_radio_and_is_unchanged_without_it():
    radio = RadioParams()
    base = ChannelParams(sigma_d_m=0.5)
    with_radio = RadioChannel(sigma_d_m=0.5, radio=radio)
    plain = AirChannel(base, np.random.default_rng(0), (1, 1))
    air = AirChannel(with_radio, np.random.default_rng(0), (1, 1))
    # beyond the horizon: lost; within: noise = floor (+) CRLB, the floor is sqrt(2) sigma_d per leg
    assert air.arrival_local_s(np.zeros(3), 0.0, np.array([30_000.0, 0, 0]), Clock(), tx_id=2) is None
    assert plain.arrival_local_s(np.zeros(3), 0.0, np.array([30_000.0, 0, 0]), Clock(), tx_id=2) is not None
    n = 4000
    floor_m = np.sqrt(2) * 0.5
    for d in (2_000.0, 20_000.0):
        expect = np.hypot(floor_m, float(link(np.zeros(3), [d, 0, 0], radio).sigma_crlb_s) * C)
        std = _errors_m(air, d, n).std()
        assert abs(std / expect - 1) < 4 / np.sqrt(2 * n) + 0.01, (d, std, expect)
    # near links keep the floor: the same keyed draws give the same noise to 5 %
    assert np.allclose(_errors_m(air, 100.0, 50), _errors_m(plain, 100.0, 50), rtol=1e-3)


def test_parse_reads_the_table_and_names_bad_keys():
    def err(msg):
        return ScenarioError(msg)

    assert parse(None, err) is None
    assert parse({}, err) == RadioParams()
    assert parse({"k_factor": 1, "two_ray": False}, err) == RadioParams(k_factor=1.0, two_ray=False)
    with pytest.raises(ScenarioError, match=r"\[radio\] power: unknown key"):
        parse({"power": 3}, err)
    with pytest.raises(ScenarioError, match=r"\[radio\] freq_hz: .* \(expected > 0\)"):
        parse({"freq_hz": 0}, err)
    with pytest.raises(ScenarioError, match=r"\[radio\] tx_power_dbm: 'x' is not a number"):
        parse({"tx_power_dbm": "x"}, err)


def test_a_scenario_radio_sees_physical_heights_in_the_network_frame(tmp_path):
    """The channel gets network-frame positions (tilted by the founders' geometry); the radio's heights
    are the physical ones: a station 30 km out at ground level is beyond a 10 m antenna's horizon of
    station 1 at ground level, and one on a 300 m mast is not."""
    from net.radio import _heights
    from net.scenario import load

    phys = [[0, 0, 0], [1000, 0, 40], [0, 1000, 20], [600, 500, 300], [30_000, 0, 0], [0, 30_000, 600]]
    text = "".join(f"[[stations]]\nid = {i + 1}\npos_m = {p}\n" for i, p in enumerate(phys))
    path = tmp_path / "radio.toml"
    path.write_text('name = "r"\nseed = 1\n[radio]\nantenna_height_m = 10.0\n' + text)
    scn = load(path)
    radio = scn.channel.radio
    assert np.allclose(_heights(scn.pos_m, radio), np.array(phys)[:, 2] + 10.0, atol=1e-6)
    assert not link(scn.pos_m[0], scn.pos_m[4], radio).exists
    assert link(scn.pos_m[0], scn.pos_m[5], radio).exists
    bad = tmp_path / "bad.toml"
    bad.write_text('name = "r"\n[radio]\nbandwidth_hz = -1\n' + text)
    with pytest.raises(ScenarioError, match=r"bad.toml: \[radio\] bandwidth_hz: -1 \(expected > 0\)"):
        load(bad)


def test_a_user_receptions_sigma_is_its_floor_and_the_links_crlb_or_no_link():
    radio = RadioParams()
    tx, near, far = np.zeros(3), np.array([2000.0, 0.0, 0.0]), np.array([40_000.0, 0.0, 0.0])
    assert reception_sigma_m(tx, far, None, 0.5) == 0.5  # no [radio]: every link, the floor
    s = reception_sigma_m(tx, near, radio, 0.5)
    assert s == pytest.approx(np.hypot(0.5, C * float(link(tx, near, radio).sigma_crlb_s)), rel=1e-12)
    assert s > 0.5
    assert reception_sigma_m(tx, far, radio, 0.5) is None  # two 10 m masts: beyond the 26 km horizon
    assert link_var_m2(s, 0.5) == pytest.approx(s**2 - 0.25, rel=1e-12)
    assert link_var_m2(0.5, 0.5) == 0.0 and link_var_m2(0.4, 0.5) == 0.0
