"""Wire schema: round trips for every kind, strict rejection of malformed payloads, drop counter."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from net import messages as M

COV = np.diag([1.0, 2.0, 3.0])


def samples() -> list[dict]:
    common = {"src": 3, "seq": 7, "stamp_s": 12.5}
    ac = {"src": "ac1", "seq": 2, "stamp_s": 3.0}
    return [
        {"kind": "range_req", **common, "dst": 5, "cycle": 12, "slot": 2, "t_tx_s": 12.02},
        {"kind": "range_rsp", **common, "dst": 5, "req_seq": 9, "turnaround_s": 0.001,
         "pos_m": np.array([1.0, 2.0, 3.0]), "cov_m2": COV, "n_updates": 4, "state": "surveying"},
        {"kind": "nav", **common, "cycle": 1, "slot": 2, "t_tx_s": 1.0, "pos_m": [0, 0, 0],
         "cov_m2": COV.tolist(), "n_updates": np.int64(3), "state": "frame",
         "ranges": [[5, 100.5, 1.01], [6, 200.0, 1.02]], "members": [1, 2, 3]},
        {"kind": "estimate", **common, "t_s": 1.0, "pos_m": [1, 2, 3], "cov_m2": COV,
         "n_updates": 10, "estimator": "dmap", "state": "surveying"},
        {"kind": "truth", **common, "t_s": 1.0, "pos_m": [1.0, 2.0, 3.0]},
        {"kind": "ac_estimate", **ac, "t_s": 1.0, "pos_m": [1, 2, 3], "cov_m2": COV, "algo": "ukf"},
        {"kind": "ac_truth", **ac, "t_s": 1.0, "pos_m": [1, 2, 3], "vel_m_s": [0, 1, 0]},
    ]


@pytest.mark.parametrize("msg", samples(), ids=lambda m: m["kind"])
def test_round_trip_every_kind(msg):
    phy = {"pos_m": np.array([10.0, 20.0, 30.0]), "t_true_s": np.float64(1.5)}
    data = M.encode(msg, phy)
    out, p = M.decode(data)
    assert out["kind"] == msg["kind"]
    assert p == {"pos_m": [10.0, 20.0, 30.0], "t_true_s": 1.5}
    for k, v in msg.items():
        assert np.allclose(np.asarray(out[k], dtype=float), np.asarray(v, dtype=float)) \
            if k not in ("kind", "state", "estimator", "algo", "src") else out[k] == v
    out2, p2 = M.decode(M.encode(msg))
    assert p2 is None and out2 == out
    # envelope shape on the wire
    env = msgpack.unpackb(data)
    assert env["v"] == 1 and set(env) == {"v", "msg", "phy"}


def test_keys():
    s = samples()
    assert M.key_for(s[0]) == "larns/station/3/range/req/5"
    assert M.key_for(s[1]) == "larns/station/3/range/rsp/5"
    assert M.key_for(s[2]) == "larns/station/3/nav"
    assert M.key_for(s[3]) == "larns/station/3/estimate"
    assert M.key_for(s[4]) == "larns/station/3/truth"
    assert M.key_for(s[5]) == "larns/aircraft/ac1/estimate/ukf"
    assert M.key_for(s[6]) == "larns/aircraft/ac1/truth"
    assert M.parse_key("larns/station/7/range/req/3") == ("station", 7, ["range", "req", "3"])
    assert M.parse_key("other/x/y") is None
    assert M.alive_key("station", 4) == "larns/alive/station/4"


def _env(msg, **kw):
    env = {"v": 1, "msg": msg, **kw}
    return msgpack.packb(env, use_bin_type=True)


def _bad_variants():
    good = samples()[1]
    g = M.to_plain(good)
    yield "garbage", b"\xc1\x00\x01"
    yield "empty", b""
    yield "not map", msgpack.packb([1, 2, 3])
    yield "version 2", msgpack.packb({"v": 2, "msg": g})
    yield "version bool", msgpack.packb({"v": True, "msg": g})
    yield "no msg", msgpack.packb({"v": 1})
    yield "extra env key", msgpack.packb({"v": 1, "msg": g, "x": 1})
    yield "unknown kind", _env({**g, "kind": "bogus"})
    yield "missing field", _env({k: v for k, v in g.items() if k != "pos_m"})
    yield "unknown field", _env({**g, "evil": 1})
    yield "pos 2", _env({**g, "pos_m": [1.0, 2.0]})
    yield "pos str", _env({**g, "pos_m": ["a", 2.0, 3.0]})
    yield "cov 3x2", _env({**g, "cov_m2": [[1, 0], [0, 1], [0, 0]]})
    yield "cov neg var", _env({**g, "cov_m2": [[-1, 0, 0], [0, 1, 0], [0, 0, 1]]})
    yield "nan", _env({**g, "turnaround_s": math.nan})
    yield "inf", _env({**g, "pos_m": [math.inf, 0, 0]})
    yield "huge", _env({**g, "pos_m": [1e300, 0, 0]})
    yield "id 0", _env({**g, "src": 0})
    yield "id big", _env({**g, "dst": 70000})
    yield "id bool", _env({**g, "dst": True})
    yield "id float", _env({**g, "dst": 5.0})
    yield "state", _env({**g, "state": "dancing"})
    yield "phy missing t", _env(g, phy={"pos_m": [0, 0, 0]})
    yield "phy nan", _env(g, phy={"pos_m": [0, 0, 0], "t_true_s": math.nan})
    yield "too big", b"\x00" * (M.MAX_PAYLOAD_BYTES + 1)
    yield "bin field", _env({**g, "pos_m": b"abc"})
    nav = M.to_plain(samples()[2])
    yield "ranges long", _env({**nav, "ranges": [[1, 1.0, 1.0]] * (M.MAX_LIST + 1)})
    yield "ranges neg", _env({**nav, "ranges": [[1, -1.0, 1.0]]})
    yield "members bad", _env({**nav, "members": ["x"]})
    yield "string src", _env({**g, "src": "3"})
    yield "ac bad name", _env({**M.to_plain(samples()[5]), "src": "a/b"})
    yield "trailing bytes", _env(g) + b"\x00"


@pytest.mark.parametrize("name,data", list(_bad_variants()), ids=[n for n, _ in _bad_variants()])
def test_malformed_rejected(name, data):
    with pytest.raises(M.MessageError):
        M.decode(data)


def test_random_fuzz_never_raises_other_errors():
    rng = np.random.default_rng(0)
    good = M.encode(samples()[2], {"pos_m": [0, 0, 0], "t_true_s": 0.0})
    n_ok = 0
    for i in range(3000):
        if i % 2:
            data = rng.integers(0, 256, rng.integers(0, 200), dtype=np.uint8).tobytes()
        else:  # bit flips of a valid message
            b = bytearray(good)
            for j in rng.integers(0, len(b), rng.integers(1, 4)):
                b[j] = int(rng.integers(0, 256))
            data = bytes(b)
        try:
            msg, _ = M.decode(data)
            n_ok += 1
            M.encode(msg)  # anything accepted is re-encodable
        except M.MessageError:
            pass
    assert n_ok < 3000


def test_encode_validates():
    with pytest.raises(M.MessageError):
        M.encode({"kind": "truth", "src": 1, "seq": 0, "stamp_s": 0.0, "t_s": 0.0, "pos_m": [0, 0]})


def test_drop_counter_rate_limited(caplog):
    t = [0.0]
    dc = M.DropCounter("st1", interval_s=5.0, clock=lambda: t[0])
    with caplog.at_level("WARNING", logger="larns.net"):
        for i in range(100):
            t[0] = i * 0.1  # 10 s in total
            try:
                M.decode(b"junk")
            except M.MessageError as e:
                dc.drop_error(e)
    assert dc.total == 100 and dc.by_reason["msgpack"] == 100
    assert dc.lines_logged == 2 and len(caplog.records) == 2
    assert dc.as_dict()["total"] == 100


def test_station_nav_intake():
    """What an aircraft or vehicle takes from the wire: a nav with its phy block on its own station's
    key; anything else is None, counted by reason."""
    nav = next(m for m in samples() if m["kind"] == "nav")
    key = M.key_for(nav)
    data = M.encode(nav, {"pos_m": [1.0, 2.0, 3.0], "t_true_s": 1.0})
    dc = M.DropCounter("ac")

    def dec(k, d):
        return M.decode(d)

    msg, phy = M.station_nav(dec, key, data, dc)
    assert msg["src"] == nav["src"] and phy["pos_m"] == [1.0, 2.0, 3.0]
    other = key.replace(f"/{nav['src']}/", f"/{nav['src'] + 1}/")
    assert M.station_nav(dec, other, data, dc) is None                      # on another station's key
    assert M.station_nav(dec, key, M.encode(nav), dc) is None               # no phy: not a broadcast
    assert M.station_nav(dec, key, b"junk", dc) is None
    assert dc.by_reason["key"] == 2 and dc.by_reason["msgpack"] == 1 and dc.total == 3
