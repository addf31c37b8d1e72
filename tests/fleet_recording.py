"""The fleet run shared by the e2e tests that read a recording (``fleet_run`` in tests/conftest.py)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from scenario_text import aircraft_hover, five_stations

PY = sys.executable
DURATION = 30.0   # fleet s: the aircraft measures for > 20 s, the vehicle drives 150 m
# speed 2, not 4: on a CPU-starved machine (a CI run whose processes got well under two cores) the
# aircraft (three filters) and the vehicle fell behind at speed 4 and published estimates for only part
# of the run; at speed 2 the run holds on 0.7 of one core (measured under a CPU quota, docs/operations.md)
SPEED = 2.0
ALGOS = ["ukf-pr", "ekf-tdoa", "lsq-pr"]
SCENARIO = five_stations("fleet_e2e", 3, extra=aircraft_hover(ALGOS))


@dataclass
class FleetRecording:
    scn: Path          # the scenario file
    rec: Path          # the fleet's recording (complete)
    killed: Path       # the second recorder's file (SIGKILLed: no footer)
    js: Path           # the fleet's JSON report
    rc: int            # the fleet's exit code
    log: str           # the fleet's stdout + stderr


def record_fleet(d: Path) -> FleetRecording:
    from net.bus import free_tcp_ports

    scn = d / "fleet_e2e.toml"
    scn.write_text(SCENARIO)
    rec, killed, js = d / "run.mcap", d / "killed.mcap", d / "fleet.json"
    (port,) = free_tcp_ports(1)
    ep = f"tcp/127.0.0.1:{port}"
    rk = subprocess.Popen([PY, "-m", "larns", "record", "-o", str(killed), "-q", "--flush", "0.5",
                           "--listen", ep], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    time.sleep(1.0)
    fleet = subprocess.Popen([PY, "-m", "larns", "fleet", "--scenario", str(scn), "--duration", str(DURATION),
                              "--speed", str(SPEED), "--aircraft", "--vehicle", "--record", str(rec), "--no-table",
                              "--json", str(js), "--connect", ep],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # kill the second recorder about 3/4 into the run (it has flushed several chunks by then)
        t0 = time.time()
        while time.time() - t0 < 90 and fleet.poll() is None:
            if killed.exists() and killed.stat().st_size > 30_000 and time.time() - t0 > 4 + 0.75 * DURATION / SPEED:
                break
            time.sleep(0.2)
        rk.send_signal(signal.SIGKILL)
        rk.wait(10)
        log, _ = fleet.communicate(timeout=180)
    finally:
        for p in (rk, fleet):
            if p.poll() is None:
                p.kill()
                p.wait(10)
    return FleetRecording(scn, rec, killed, js, fleet.returncode, log)
