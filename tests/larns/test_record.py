"""`larns record`: real Zenoh traffic from another process, read back with the MCAP reader."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time

import pytest
from mcap.reader import make_reader

from net import messages as M
from net.bus import free_tcp_ports

pytestmark = pytest.mark.e2e

PUBLISHER = textwrap.dedent("""
    import sys, time
    from net.bus import Bus
    from net import messages as M
    b = Bus(listen=[sys.argv[1]], connect=[sys.argv[2]])
    t0 = time.time()
    while not b.alive("larns/alive/recorder/*", 0.5) and time.time() - t0 < 20:
        time.sleep(0.1)
    time.sleep(0.5)
    for i in range(50):
        for sid in (2, 3):
            m = {"kind": "truth", "src": sid, "seq": i, "stamp_s": 0.1 * i, "t_s": 0.1 * i,
                 "pos_m": [float(sid), 0.0, float(i)]}
            b.publish(M.key_for(m), M.encode(m, {"pos_m": [1, 2, 3], "t_true_s": 0.1 * i}))
        b.publish("larns/station/2/nav", b"junk-is-recorded-too")
        time.sleep(0.005)
    time.sleep(0.5)
    b.close()
""")


def test_record_real_traffic(tmp_path):
    out = tmp_path / "run.mcap"
    p_rec, p_pub = free_tcp_ports(2)
    epoch = time.time()
    rec = subprocess.Popen([sys.executable, "-m", "larns", "record", "-o", str(out), "-q",
                            "--listen", f"tcp/127.0.0.1:{p_rec}", "--scenario", "unit",
                            "--epoch", repr(epoch), "--speed", "2", "--flush", "0.5"])
    pub = subprocess.run([sys.executable, "-c", PUBLISHER, f"tcp/127.0.0.1:{p_pub}",
                          f"tcp/127.0.0.1:{p_rec}"], timeout=60)
    assert pub.returncode == 0
    rec.send_signal(signal.SIGINT)
    assert rec.wait(timeout=20) == 0

    with open(out, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        md = {m.name: m.metadata for m in reader.iter_metadata()}
        msgs = list(reader.iter_messages())
    assert md["larns"]["scenario"] == "unit"
    assert float(md["larns"]["epoch_unix_s"]) == epoch
    # wire channels (the Foxglove JSON view channels larns/foxglove/** are tested in tests/larns/test_replay.py)
    topics = {c.topic: c for c in summary.channels.values() if not c.topic.startswith("larns/foxglove/")}
    assert set(topics) == {"larns/station/2/truth", "larns/station/3/truth", "larns/station/2/nav"}
    assert all(c.message_encoding == "msgpack" for c in topics.values())
    by_topic: dict[str, list] = {}
    for schema, ch, m in msgs:
        if ch.topic.startswith("larns/foxglove/"):
            continue
        by_topic.setdefault(ch.topic, []).append(m)
    assert len(by_topic["larns/station/2/truth"]) == 50
    assert len(by_topic["larns/station/3/truth"]) == 50
    assert all(m.data == b"junk-is-recorded-too" for m in by_topic["larns/station/2/nav"])
    for sid in (2, 3):
        for i, m in enumerate(by_topic[f"larns/station/{sid}/truth"]):
            msg, phy = M.decode(m.data)  # exact wire bytes, phy included
            assert msg["seq"] == i and msg["pos_m"] == [float(sid), 0.0, float(i)]
            assert phy["t_true_s"] == pytest.approx(0.1 * i)
            assert m.publish_time == round((epoch + 0.1 * i / 2.0) * 1e9)
            assert abs(m.log_time - time.time_ns()) < 120e9
    # junk has no stamp: publish_time falls back to receive time
    assert all(m.publish_time == m.log_time for m in by_topic["larns/station/2/nav"])
