"""The core journal: what the shell policy publishes (``stations/shell.py``) against the two readers
that validate it - ``net.messages.decode`` (the schema, ``_journal``) and the offline decoder
(``larns.log.series.decode_input``, which validates each distinct embedded air message once). Valid
journals decode identically in both and re-estimate bit for bit; malformed ones are rejected by both,
and a rejected input leaves a hole at which offline re-estimation stops (reported, not papered over).
"""

from __future__ import annotations

import math

import msgpack
import pytest

from larns.log import Msg
from larns.analysis.offline import reestimate_station
from larns.log.series import collect_journals, decode_input
from net import messages as M
from net.scenario import load
from stations.shell import PublishPolicy
from stations.sim import Simulator


@pytest.fixture(scope="module")
def published():
    """Six seconds of a 4-station network with journals on: [(t_s, msg, phy)] as the shells publish."""
    out = []
    sim = Simulator(load("seed000", seed=4, layout={"n": 4}), journal=True,
                    publish=lambda t, _sid, m, phy: out.append((t, m, phy)))
    sim.run(6.0, [6.0])
    return out


def _records(published, encode=lambda m: M.encode(m, validate=False)):
    """The published station messages as recorded (journal encoded like the node: not re-validated)."""
    recs = []
    for i, (t, m, phy) in enumerate(published):
        if m["kind"] in ("core_init", "core_input", "estimate"):
            data = encode(m) if m["kind"] == "core_input" else M.encode(m, phy)
            recs.append(Msg(M.key_for(m), int(t * 1e9) + i, int(t * 1e9), i, data))
    return recs


def _inputs(published):
    return [m for _t, m, _p in published if m["kind"] == "core_input"]


def test_the_policy_journals_every_nav_and_an_init_every_ten(published):
    for sid in (1, 2, 3, 4):
        mine = [m for _t, m, _p in published if m.get("src") == sid]
        navs = sum(m["kind"] == "nav" for m in mine)
        inits = [m for m in mine if m["kind"] == "core_init"]
        inputs = [m for m in mine if m["kind"] == "core_input"]
        assert navs >= 5 and len(inputs) == navs
        assert len(inits) == 1 + navs // PublishPolicy(sid).init_every_navs
        assert [m["seq"] for m in inputs] == list(range(1, navs + 1))


def test_both_validators_decode_the_published_journal_identically(published):
    cache: dict = {}
    inputs = _inputs(published)
    assert sum(len(m["entries"]) for m in inputs) > 50
    for m in inputs:
        data = M.encode(m, validate=False)  # as the node sends it
        assert data == M.encode(m)  # the core's entries are already in normalized form
        a = M.decode(data)[0]
        b = decode_input(data, cache)
        assert a == b
        assert any(e[0] == "m" for e in b["entries"]) or len(b["entries"]) <= 2
    assert 0 < len(cache) < sum(e[0] == "m" for m in inputs for e in m["entries"])  # shared navs decoded once


def test_the_recorded_journal_re_estimates_bit_for_bit(published):
    journals = collect_journals(_records(published), strict=True)
    assert sorted(journals) == [1, 2, 3, 4]
    for j in journals.values():
        r = reestimate_station(j)
        assert r.error is None and r.missing_from is None
        assert r.compared == len(j.estimates) > 3 and r.bit_exact
        # the replayed estimates carry the shell's decoration too (slot from the same policy)
        assert all(o.get("slot") == j.estimates[o["seq"]][1].get("slot") for _l, _p, o in r.estimates)


def test_a_secure_fleets_signed_journal_re_estimates_bit_for_bit(published, tmp_path, monkeypatch):
    """A ``--secure`` fleet records every message as its signed frame: the offline decoder takes the
    envelope inside (as ``net.messages.decode`` does; it read nothing of a secure recording's station
    journals before), and the journal re-estimates bit for bit."""
    from net.keystore import init_keystore
    from net.security import Security

    monkeypatch.setenv("LARNS_STATE_DIR", str(tmp_path / "state"))
    ks = init_keystore(tmp_path / "keys", [1, 2, 3, 4], []).root
    sec = {sid: Security(ks, f"station-{sid}") for sid in (1, 2, 3, 4)}
    recs = []
    for r in _records(published):
        signed = sec[int(r.topic.split("/")[2])].seal(r.topic, r.data)
        assert signed[:1] == M.SIGNED_MARK
        recs.append(Msg(r.topic, r.log_time, r.publish_time, r.sequence, signed))
    journals = collect_journals(recs, strict=True)
    assert sorted(journals) == [1, 2, 3, 4]
    for j in journals.values():
        res = reestimate_station(j)
        assert res.error is None and res.compared == len(j.estimates) > 3 and res.bit_exact


def _bad_entries(nav):
    return {
        "entries not a list": 3,
        "unknown entry tag": [["x", 1.0]],
        "timer time not a number": [["t", "soon"]],
        "timer time not finite": [["t", math.inf]],
        "message entry too short": [["m", 1.0]],
        "not an air message": [["m", 1.0, {"kind": "truth", "src": 2, "seq": 1, "stamp_s": 1.0, "t_s": 1.0,
                                           "pos_m": [0.0, 0.0, 0.0]}]],
        "air message missing a field": [["m", 1.0, {k: v for k, v in nav.items() if k != "pos_m"}]],
        "air message bad value": [["m", 1.0, {**nav, "cov_m2": [[1.0, 0.0, 0.0]] * 2}]],
        "too many entries": [["t", 1.0]] * (M.MAX_JOURNAL + 1),
    }


def test_both_validators_reject_the_same_malformed_journals(published):
    good = _inputs(published)[3]
    nav = next(e[2] for m in _inputs(published) for e in m["entries"] if e[0] == "m" and e[2]["kind"] == "nav")
    for what, entries in _bad_entries(nav).items():
        data = msgpack.packb({"v": M.VERSION, "msg": {**good, "entries": entries}}, use_bin_type=True)
        with pytest.raises(M.MessageError) as a:
            M.decode(data)
        with pytest.raises(M.MessageError) as b:
            decode_input(data, {})
        assert a.value.reason and b.value.reason, what
    # an envelope with a stray key is not a journal for either
    data = msgpack.packb({"v": M.VERSION, "msg": good, "phy": {"pos_m": [0.0] * 3, "t_true_s": 0.0}},
                         use_bin_type=True, default=M._plain)
    with pytest.raises(M.MessageError):
        decode_input(data, {})


def test_a_rejected_input_is_a_hole_where_re_estimation_stops(published):
    recs = _records(published)
    sid = 3
    idx = [i for i, r in enumerate(recs) if r.topic == f"larns/station/{sid}/input"]
    bad = recs[idx[2]]
    msg = M.decode(bad.data)[0]
    broken = msgpack.packb({"v": M.VERSION, "msg": {**msg, "entries": [["t", "soon"]]}}, use_bin_type=True)
    recs[idx[2]] = Msg(bad.topic, bad.log_time, bad.publish_time, bad.sequence, broken)
    j = collect_journals(recs, strict=True)[sid]
    assert 3 not in j.inputs  # counted out by the strict reader, not replayed
    r = reestimate_station(j)
    assert r.missing_from == 3 and r.n_inputs == 2
    assert r.bit_exact and r.compared == len(r.estimates) < len(j.estimates)
