"""Issue 32, the recorder's half: a full disk (here a file-size limit, RLIMIT_FSIZE) finishes the
file with what it has and exits with one clear line; a flood of keys cannot open unbounded channels;
``larns recover`` streams."""

from __future__ import annotations

import resource
import subprocess
import sys
import textwrap
import time

import pytest

from larns.log.reader import read_log
from net.bus import free_tcp_ports

FLOOD = textwrap.dedent("""
    import os, sys, time
    from net.bus import Bus
    b = Bus(listen=[sys.argv[1]], connect=[sys.argv[2]])
    t0 = time.time()
    while not b.alive("larns/alive/recorder/*", 0.5) and time.time() - t0 < 20:
        time.sleep(0.1)
    time.sleep(0.3)
    t0 = time.time()
    while time.time() - t0 < float(sys.argv[3]):  # incompressible samples
        b.publish("larns/station/2/nav", os.urandom(2000))
        time.sleep(0.0005)
    b.close()
""")


def _limit_file_size(n_bytes: int):
    def pre():
        resource.setrlimit(resource.RLIMIT_FSIZE, (n_bytes, n_bytes))
    return pre


@pytest.mark.e2e
def test_recorder_on_a_full_disk_finishes_the_file_and_exits_with_a_clear_error(tmp_path):
    out = tmp_path / "full.mcap"
    limit = 600_000
    p_rec, p_pub = free_tcp_ports(2)
    rec = subprocess.Popen([sys.executable, "-m", "larns", "record", "-o", str(out), "-q", "--no-foxglove",
                            "--listen", f"tcp/127.0.0.1:{p_rec}", "--flush", "0.2", "--duration", "30"],
                           stderr=subprocess.PIPE, text=True, preexec_fn=_limit_file_size(limit))
    pub = subprocess.Popen([sys.executable, "-c", FLOOD, f"tcp/127.0.0.1:{p_pub}", f"tcp/127.0.0.1:{p_rec}", "8"])
    try:
        rc = rec.wait(timeout=40)
    finally:
        pub.wait(timeout=30)
    err = rec.stderr.read()
    assert rc == 1, err
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("larns record:")]
    assert len(lines) == 1 and "File too large" in lines[0] and "finished" in lines[0], err
    assert "Traceback" not in err
    assert 0 < out.stat().st_size <= limit
    lg = read_log(out)
    assert lg.complete and lg.error is None, lg.error
    assert len(lg.messages) > 50 and all(len(m.data) == 2000 for m in lg.messages)


def test_writer_finishes_the_file_when_a_write_fails(tmp_path):
    """The same path in-process: a file-size limit in a child; every message written before the last
    whole chunk is readable and the file has its footer."""
    code = textwrap.dedent(f"""
        import os, resource, signal
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (200_000, 200_000))
        from larns.log.writer import LogWriter, LogWriteError
        w = LogWriter({str(tmp_path / 'w.mcap')!r}, {{"larns": {{"k": "v"}}}}, chunk_size=16_384)
        n = 0
        try:
            for i in range(10_000):
                w.write("larns/x", os.urandom(1000), i, i)
                n += 1
        except LogWriteError as e:
            print("ERR", n, e)
        try:
            w.write("larns/x", b"more", 0, 0)
        except LogWriteError:
            print("REFUSED")
        w.finish()
    """)
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "ERR" in r.stdout and "REFUSED" in r.stdout and "File too large" in r.stdout
    n_written = int(r.stdout.split()[1])
    lg = read_log(tmp_path / "w.mcap")
    assert lg.complete and lg.error is None
    assert lg.metadata["larns"] == {"k": "v"}
    assert 100 < len(lg.messages) <= n_written
    assert [m.log_time for m in lg.messages] == list(range(len(lg.messages)))  # a prefix, none lost inside


def test_channels_per_source_are_capped(tmp_path):
    from larns.log.record import MAX_CHANNELS_PER_SOURCE, McapSink

    sink = McapSink(tmp_path / "c.mcap", foxglove=False)
    for i in range(MAX_CHANNELS_PER_SOURCE + 100):
        sink.write(f"larns/station/2/x{i}", b"\x80", time.time_ns())
    sink.write("larns/station/3/nav", b"\x80", time.time_ns())
    sink.write("larns/station/2/x0", b"\x80", time.time_ns())  # a key it has: still written
    sink.finish()
    assert len(sink.channels) == MAX_CHANNELS_PER_SOURCE + 1
    assert sink.refused_keys == 100
    lg = read_log(tmp_path / "c.mcap")
    assert lg.complete and len(lg.messages) == MAX_CHANNELS_PER_SOURCE + 2


def test_recover_streams_in_constant_memory(tmp_path):
    """`larns recover` of a killed 40 MB recording: every message kept, peak memory far below it."""
    src = tmp_path / "big.mcap"
    code = textwrap.dedent(f"""
        import os
        from larns.log.writer import LogWriter
        w = LogWriter({str(src)!r}, {{"larns": {{"k": "v"}}}})
        for i in range(20_000):
            w.write("larns/station/%d/nav" % (i % 7 + 1), os.urandom(2000), i, i)
        w.flush()
        os._exit(0)  # killed: no summary, no footer
    """)
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
    assert src.stat().st_size > 40e6
    dst = tmp_path / "clean.mcap"
    probe = textwrap.dedent(f"""
        import resource, json
        from larns.log.recover import recover
        r = recover({str(src)!r}, {str(dst)!r})
        print(json.dumps([r["messages"], r["source_complete"], resource.getrusage(resource.RUSAGE_SELF).ru_maxrss]))
    """)
    base = subprocess.run([sys.executable, "-c", "import resource, larns.log.recover, mcap.writer, mcap.stream_reader;"
                           "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)"],
                          capture_output=True, text=True, check=True)
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, timeout=120)
    import json

    n, complete, rss_kb = json.loads(r.stdout)
    assert n == 20_000 and complete is False
    assert rss_kb - int(base.stdout) < 25_000, (rss_kb, base.stdout)  # < 25 MB over the interpreter, file 40 MB
    lg = read_log(dst)
    assert lg.complete and len(lg.messages) == 20_000
    assert lg.metadata["larns"] == {"k": "v"} and lg.metadata["larns_recover"]["messages"] == "20000"

