"""net/cli.py: the processes' shared command line (stations and aircraft parse the same common flags)
and ``serve`` (bad options -> a clear error, the bus always closed, the JSON report)."""

from __future__ import annotations

import argparse
import json
import signal

import pytest

from net import cli


class FakeBus:
    closed = False

    def close(self):
        self.closed = True


def test_station_and_aircraft_share_the_common_flags():
    from aircraft.node import build_parser as aircraft_parser
    from stations.node import build_parser as station_parser

    common = ["--speed", "2", "--epoch", "100.5", "--duration", "30", "--seed", "9", "--n-stations", "12",
              "--net-loss", "0.1", "--status-every", "0", "--report-json", "-q"]
    s = vars(station_parser().parse_args(["--id", "4", *common]))
    a = vars(aircraft_parser().parse_args(common))
    keys = ("speed", "epoch", "duration", "seed", "n_stations", "net_loss", "status_every", "report_json", "quiet")
    assert {k: s[k] for k in keys} == {k: a[k] for k in keys} == {
        "speed": 2.0, "epoch": 100.5, "duration": 30.0, "seed": 9, "n_stations": 12, "net_loss": 0.1,
        "status_every": 0.0, "report_json": True, "quiet": True}
    assert s["scenario"] == "seed000" and a["scenario"] == "seed003"
    # the aircraft accepts the network-fault flags for the launcher but does not show them
    assert "--net-loss" in station_parser().format_help() and "--net-loss" not in aircraft_parser().format_help()


def test_serve_runs_the_node_and_prints_its_report(capsys):
    class Node:
        def run(self):
            return {"ok": 1}

        def stop(self, *_):
            pass

    old = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    try:
        bus = FakeBus()
        rep = cli.serve(argparse.Namespace(report_json=True), bus, Node)
    finally:
        signal.signal(signal.SIGINT, old[0])
        signal.signal(signal.SIGTERM, old[1])
    assert rep == {"ok": 1} and bus.closed
    assert json.loads(capsys.readouterr().out) == {"ok": 1}


def test_serve_reports_bad_options_and_closes_the_bus(capsys):
    def bad():
        raise ValueError("station 99 is not in scenario seed000")

    bus = FakeBus()
    assert cli.serve(argparse.Namespace(report_json=True), bus, bad) is None
    assert bus.closed
    assert "error: station 99" in capsys.readouterr().err


def test_open_bus_turns_credential_errors_into_exit_2(capsys):
    from net.security import KeystoreError

    def no_keys():
        raise KeystoreError("no keystore at /nowhere")

    with pytest.raises(SystemExit) as ei:
        cli.open_bus("station 3", no_keys)
    assert ei.value.code == 2 and "station 3: --secure: no keystore" in capsys.readouterr().err
