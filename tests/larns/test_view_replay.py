"""`larns replay --view`: a recording served on a Foxglove WebSocket, Foxglove's playback controls
(play, pause, speed, seek) driving the player (issue 34, item 2); the player's arithmetic alone."""

from __future__ import annotations

import asyncio
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from foxglove_ws import FoxgloveClient
from net import messages as M

from larns.log.player import SeekablePlayer

PY = sys.executable
EPOCH = 1_700_000_000.0
T_END_S = 30.0


def _recording(path: Path) -> None:
    """A real MCAP file as the recorder writes it: station 2's estimates and truths every 0.1 fleet s
    (fleet epoch and speed 1 in the metadata, log time = wall time of the fleet instant)."""
    from larns.log import LogWriter

    cov = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    with LogWriter(path, {"larns": {"epoch_unix_s": repr(EPOCH), "speed": "1.0", "scenario": "unit"}}) as w:
        for k in range(int(T_END_S * 10) + 1):
            t = k / 10
            ns = int(round((EPOCH + t) * 1e9))
            est = {"kind": "estimate", "src": 2, "seq": k, "stamp_s": t, "t_s": t, "pos_m": [100.0, 0.0, t],
                   "cov_m2": cov, "n_updates": k, "estimator": "dmap", "state": "surveying"}
            tru = {"kind": "truth", "src": 2, "seq": k, "stamp_s": t, "t_s": t, "pos_m": [100.0, 0.0, 0.0]}
            w.write(M.key_for(est), M.encode(est), ns, ns)
            w.write(M.key_for(tru), M.encode(tru), ns + 1000, ns + 1000)
        w.write("larns/station/2/nav", b"not msgpack at all", ns + 2000, ns + 2000)


def test_seekable_player_pause_speed_seek():
    times = [i * 100_000_000 for i in range(101)]  # 0..10 s every 0.1 s
    p = SeekablePlayer(times, now_s=0.0)
    due, cur = p.step(1.0)
    assert list(due) == list(range(11)) and cur == 1_000_000_000
    p.control(False, 1.0, None, now_s=1.5)  # pause at 1.5 s
    assert list(p.step(5.0)[0]) == list(range(11, 16)) and p.step(9.0)[1] == 1_500_000_000
    p.control(True, 2.0, 8_000_000_000, now_s=9.0)  # seek to 8 s, play at 2x
    due, cur = p.step(9.5)
    assert list(due) == list(range(80, 91)) and cur == 9_000_000_000 and p.seeks == 1
    p.control(True, 2.0, 0, now_s=9.5)  # seek back to the start
    assert list(p.step(9.5)[0]) == [0]
    assert not p.ended and list(p.step(100.0)[0])[-1] == 100 and p.ended
    p.control(True, float("nan"), None, now_s=100.0)  # a nonsense speed is ignored
    assert p.speed == 2.0


def _t(got, after_wall: float = 0.0) -> list[float]:
    return [m["t_s"] for wall, topic, _, m in got.messages if topic == "larns/foxglove/station/2" and wall > after_wall]


@pytest.mark.e2e
def test_replay_view_obeys_pause_and_seek(tmp_path: Path):
    from net.bus import free_tcp_ports

    rec = tmp_path / "run.mcap"
    _recording(rec)
    (port,) = free_tcp_ports(1)
    proc = subprocess.Popen([PY, "-m", "larns", "replay", str(rec), "--view", str(port), "--view-duration", "60",
                             "--json"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        async def drive():
            t_end = time.monotonic() + 30
            while True:
                try:
                    client = FoxgloveClient(f"ws://127.0.0.1:{port}")
                    await client.__aenter__()
                    break
                except OSError:
                    if time.monotonic() > t_end:
                        raise
                    await asyncio.sleep(0.2)
            c = client
            try:
                await c.run(1.5)
                playing = _t(c.got)
                await c.playback(1)                      # pause
                await c.run(0.4)
                t_pause = time.time()
                await c.run(1.5)
                paused = _t(c.got, t_pause)
                await c.playback(0, speed=1.0, seek_ns=20_000_000_000)  # seek to fleet 20 s and play
                t_seek = time.time()
                await c.run(1.5)
                after_seek = _t(c.got, t_seek)
                await c.playback(0, speed=4.0)           # 4x
                t_fast = time.time()
                await c.run(1.0)
                fast = _t(c.got, t_fast)
                return c.got, playing, paused, after_seek, fast
            finally:
                await c.__aexit__(None, None, None)

        got, playing, paused, after_seek, fast = asyncio.run(drive())
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err[-2000:]
    assert "playbackControl" in got.info["capabilities"] and "time" in got.info["capabilities"]
    assert got.undecodable == []
    # playing from the start at rate 1: about the first 1.5 fleet s
    assert playing and playing[0] == 0.0 and 0.5 <= playing[-1] <= 3.0, playing[-3:]
    assert paused == []                               # nothing while paused
    # the seek: playback continues at 20 s (nothing between the pause point and 20 s is sent)
    assert after_seek and 20.0 <= after_seek[0] <= 20.5 and after_seek[-1] <= 23.0, after_seek[:3]
    assert all(t >= 20.0 for t in after_seek)
    # 4x: about 4 fleet s in 1 wall s
    assert fast and fast[-1] - fast[0] >= 2.5, (fast[0], fast[-1])
    # the server's time is the player's time (fleet ns): it moved to the seek target
    assert any(20e9 <= t <= 30e9 for t in got.times_ns)
    assert '"seeks": 1' in out
