"""`larns export run.mcap -o out.mcap`: the recording plus the Foxglove JSON channels
(:mod:`larns.viz.foxglove`); `--geojson / --kml / --csv / --nmea`: the recording on the map
(:mod:`larns.analysis.geoexport`, :mod:`larns.analysis.nmea`)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

EXPORT_DESCRIPTION = """\
Export a recording for viewers and maps.

-o OUT.mcap copies the recording and adds the Foxglove JSON channels (3D scene, transforms,
plottable estimates and errors; with a site also foxglove.LocationFix for the Map panel).

With a site - the scenario's [site] (docs/scenarios.md, "Sites on the Earth"), which the recorder
stores in the recording, or --scenario NAME|FILE - the recording also goes on the map:
--geojson OUT (RFC 7946) and --kml OUT write every station's last estimate as a Point with its
sigmas and 2-sigma horizontal error ellipse (and a Polygon of that ellipse), the aircraft and
vehicle tracks as LineStrings, and the truth as separate features (property kind); --nmea OUT
writes GGA and RMC sentences of an aircraft's estimated track. --csv OUT (no site needed) writes
the surveyed coordinates with their sigmas (and latitude, longitude, height with a site)."""


def _site(args: argparse.Namespace, logs):
    from larns.viz.foxglove import recording_site

    return recording_site(logs, args.scenario)


def _nmea(rec, site, algo: str | None) -> tuple[list[str], str]:
    from larns.analysis.nmea import track_sentences

    for name in sorted(rec.aircraft):
        a = rec.aircraft[name]
        for al in ([algo] if algo else a.algos):
            if al in a.estimates:
                tr = a.track(al)
                epoch = float(rec.meta.get("epoch_unix_s", 0.0))
                return track_sentences(site, epoch, tr["t_s"], tr["pos_m"], tr["cov_m2"],
                                       n_used=len(rec.stations)), f"{name} {al}"
    return [], ""


def _map_outputs(args: argparse.Namespace, logs, site) -> list[str]:
    """--geojson / --kml / --csv / --nmea; returns the lines to print."""
    from larns.analysis import geoexport as G
    from larns.log.series import Recording

    rec = Recording.from_logs(logs)
    done = []
    if args.geojson:
        doc = G.geojson(rec, site)
        Path(args.geojson).write_text(json.dumps(doc, allow_nan=False))
        done.append(f"[export] {len(doc['features'])} GeoJSON features -> {args.geojson}")
    if args.kml:
        Path(args.kml).write_text(G.kml(rec, site, name=Path(args.files[0]).stem))
        done.append(f"[export] KML -> {args.kml}")
    if args.csv:
        text = G.csv_text(rec, site)
        Path(args.csv).write_text(text)
        done.append(f"[export] {text.count(chr(10)) - 1} stations (CSV{', with lat/lon/h' if site else ''}) -> "
                    f"{args.csv}")
    if args.nmea:
        lines, what = _nmea(rec, site, args.nmea_algo)
        if not lines:
            raise ValueError("--nmea: no aircraft estimates in the recording" +
                             (f" of algorithm {args.nmea_algo}" if args.nmea_algo else "") +
                             " (expected a recording with an aircraft)")
        Path(args.nmea).write_text("\r\n".join(lines) + "\r\n")
        done.append(f"[export] {len(lines)} NMEA sentences ({what}) -> {args.nmea}")
    return done


def cmd_export(args: argparse.Namespace) -> int:
    from larns.log import read_logs
    from larns.viz.foxglove import export
    from net.scenario import ScenarioError

    if not (args.output or args.geojson or args.kml or args.csv or args.nmea):
        print("larns export: nothing to write (expected -o OUT.mcap, --geojson, --kml, --csv or --nmea)",
              file=sys.stderr)
        return 2
    try:
        logs = read_logs(args.files)
        site = _site(args, logs)
    except ScenarioError as e:
        print(e, file=sys.stderr)
        return 2
    except (OSError, ValueError) as e:
        print(f"larns export: {e}", file=sys.stderr)
        return 2
    need = [f for f, v in (("--geojson", args.geojson), ("--kml", args.kml), ("--nmea", args.nmea)) if v]
    if need and site is None:
        print(f"larns export: {need[0]}: {args.files[0]} has no site: its scenario has no [site] (expected a "
              "recording of a scenario with [site] origin, or --scenario NAME|FILE with one)", file=sys.stderr)
        return 2
    try:
        lines = _map_outputs(args, logs, site) if (args.geojson or args.kml or args.csv or args.nmea) else []
        r = export(args.files, args.output, site) if args.output else None
    except (OSError, ValueError) as e:
        print(f"larns export: {e}", file=sys.stderr)
        return 1
    for line in lines:
        print(line, file=sys.stderr)
    if r is not None:
        print(f"[export] {r['messages']} wire messages + {r['json_messages']} Foxglove JSON messages -> "
              f"{r['output']}", file=sys.stderr)
    if args.json:
        print(json.dumps(r or {"outputs": lines}))
    return 0


def register(sub) -> None:
    from .helptext import Formatter, examples

    p = sub.add_parser(
        "export", help="Foxglove channels for a recording (-o), or the recording on the map: GeoJSON, KML, "
                       "CSV, NMEA",
        description=EXPORT_DESCRIPTION, formatter_class=Formatter,
        epilog=examples(
            "larns export runs/demo.mcap -o runs/demo-foxglove.mcap",
            "larns export runs/geo.mcap --geojson runs/geo.geojson --kml runs/geo.kml --csv runs/geo.csv",
            "larns export runs/demo.mcap --csv runs/demo-stations.csv",
            "larns export runs/demo.mcap --scenario seed000-geo --geojson runs/demo.geojson   # a site afterwards",
        ))
    p.add_argument("files", nargs="+", help="MCAP recording(s), merged by log time")
    p.add_argument("-o", "--output", default=None, help="output .mcap (wire channels + JSON channels)")
    p.add_argument("--geojson", default=None, metavar="OUT",
                   help="write stations (estimate, sigmas, 2-sigma ellipse), tracks and truth as GeoJSON "
                        "(needs a site)")
    p.add_argument("--kml", default=None, metavar="OUT", help="the same as KML (needs a site)")
    p.add_argument("--csv", default=None, metavar="OUT",
                   help="the surveyed coordinates with sigmas (lat/lon/h too with a site)")
    p.add_argument("--nmea", default=None, metavar="OUT",
                   help="NMEA GGA + RMC of the aircraft's estimated track (needs a site)")
    p.add_argument("--nmea-algo", default=None, metavar="ALGO",
                   help="the aircraft algorithm for --nmea (default: the first recorded)")
    p.add_argument("--scenario", default=None, metavar="NAME|FILE",
                   help="take the site from this scenario's [site] (default: the recording's own site)")
    p.add_argument("--json", action="store_true", help="print statistics as JSON")
    p.set_defaults(func=cmd_export)
