"""aircraft/events.py: the typed events of the live cores become messages of the wire schema
(net/messages.py validates them) only through ``to_msg``; optional estimate fields appear only when set."""

from __future__ import annotations

import pytest

from aircraft.events import AcEstimate, AcStatus, AcTruth, JournalEvent, to_msgs
from net import messages as M

EVENTS = [
    AcTruth("ac1", 3, 12.5, [1.0, 2.0, 3.0], [0.5, 0.0, -0.1]),
    AcEstimate("ac1", 7, 12.5, "ukf-pr", [1.0, 2.0, 3.0], [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 2.0]], 40,
               vel_m_s=[0.5, 0.0, 0.0], hpl_m=4.2, vpl_m=7.9, excluded=[6]),
    AcEstimate("ac1", 8, 13.0, "ins-ekf", [1.0, 2.0, 3.0], [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 2.0]], 41,
               vel_m_s=[0.5, 0.0, 0.0], vel_cov=[[0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1]], extra={"roll_rad": 0.01}),
    AcStatus("ac1", 2, 13.0, "ukf-pr", "tracking", "tracking", {"measurements": 10.0}),
    JournalEvent("ac_init", "ac1", 1, 0.0, {"record": {"kind": "radio", "algos": ["ukf-pr"], "tuning": {},
                                                        "init_sigma_m": None}}),
    JournalEvent("ac_input", "ac1", 1, 1.0, {"entries": [["m", 0.5, 1, [0.0, 0.0, 0.0],
                                                          [[0.0] * 3] * 3, 0.0, 1000.0]]}),
]


@pytest.mark.parametrize("ev", EVENTS, ids=lambda e: e.to_msg()["kind"])
def test_every_event_is_a_valid_wire_message_that_round_trips(ev):
    m = ev.to_msg()
    assert m["kind"] == ev.kind and m["src"] == "ac1" and m["seq"] == ev.seq
    back = M.decode(M.encode(m))[0]
    assert back == M.validate_msg(m)


def test_an_estimate_carries_its_optional_fields_only_when_set():
    plain = AcEstimate("ac1", 1, 1.0, "lsq-pr", [0.0, 0.0, 0.0], [[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]], 1).to_msg()
    assert set(plain) == {"kind", "src", "seq", "stamp_s", "t_s", "pos_m", "cov_m2", "algo", "n_updates"}
    assert [m["kind"] for m in to_msgs(EVENTS)] == ["ac_truth", "ac_estimate", "ac_estimate", "ac_status",
                                                    "ac_init", "ac_input"]
    with pytest.raises(AttributeError):  # frozen: an event is what the core said, not a mutable record
        EVENTS[0].seq = 4
