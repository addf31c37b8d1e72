"""`larns scenario list | show NAME | validate FILE...`: the packaged scenarios, one scenario as the
emulator resolves it (defaults filled in, stations in the network frame), and a check of scenario
files before a launch.

    larns scenario list
    larns scenario show seed003
    larns scenario validate my.toml other.toml     # exit 0: all valid; 2: one line per bad file

``validate`` runs the loader every command uses (``net/scenario.py``: syntax, unknown keys and
sections, estimator and algorithm names, TDMA slots, frame geometry) and then the checks of the
aircraft's table (``aircraft/config.py``) and of ``[aircraft.crlb]`` (``larns crlb``), so what a launch
would refuse in the file is found before it. Each bad file gives one line ``FILE: [section] key: what
is wrong (expected ...)`` on stderr. Format: docs/scenarios.md.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import asdict, replace


DESCRIPTION = """\
Scenario files describe a world: the stations and their layout, the TDMA plan, the air channel,
the oscillators, faults, and the aircraft's table (docs/scenarios.md). Every command that takes
--scenario accepts a packaged name (seed000, seed003, ...) or a TOML file of your own.

  list      the packaged scenarios and their descriptions
  show      one scenario as the emulator resolves it: defaults filled in, stations in the
            network frame
  validate  check files before a launch, with the checks a launch would make; each bad file
            gives one line FILE: [section] key: what is wrong (expected ...); exit 0 if all
            are valid, else 2"""

VALIDATE_DESCRIPTION = """\
Check scenario files with the loader every command uses (syntax, unknown keys and sections,
estimator and algorithm names, TDMA slots, frame geometry), then the aircraft's table and
[aircraft.crlb] (`larns crlb`): what a launch would refuse is found before it. Prints
`FILE: ok (...)` per valid file on stdout and one line per bad file on stderr; exit 0 if all
are valid, else 2."""


def register(sub) -> None:
    from .helptext import Formatter, add_parser, examples

    p = add_parser(sub, "scenario", help="list the packaged scenarios, show one resolved, validate files",
                   description=DESCRIPTION,
                   example=["larns scenario list",
                            "larns scenario show seed003                  # seed003 resolved, defaults filled in",
                            "larns scenario show my.toml                  # your own file (e.g. an edited copy of one)",
                            "larns scenario validate my.toml seed000      # exit 0: all valid; 2: a line per bad file"])
    ssub = p.add_subparsers(dest="action", metavar="ACTION")
    ls = ssub.add_parser("list", help="the packaged scenarios (names for --scenario)",
                         description="The packaged scenarios (names for --scenario) and their descriptions.",
                         epilog=examples("larns scenario list"), formatter_class=Formatter)
    ls.set_defaults(func=cmd_list)
    show = ssub.add_parser("show", help="one scenario as the emulator resolves it (defaults filled in)",
                           description="One scenario as the emulator resolves it: every value it uses, "
                                       "defaults filled in,\nand the stations in the network frame. A bad "
                                       "file is one line and exit 2.",
                           epilog=examples("larns scenario show seed003",
                                           "larns scenario show my.toml     # your own file"),
                           formatter_class=Formatter)
    show.add_argument("name", metavar="NAME", help="packaged scenario name or TOML file")
    show.set_defaults(func=cmd_show)
    val = ssub.add_parser("validate", help="check scenario files: exit 0 if all are valid, else 2",
                          description=VALIDATE_DESCRIPTION, formatter_class=Formatter,
                          epilog=examples("larns scenario validate my.toml other.toml",
                                          "larns scenario validate -q seed000 seed003 my.toml   # only the errors"))
    val.add_argument("files", nargs="+", metavar="FILE", help="TOML files (or packaged names)")
    val.add_argument("-q", "--quiet", action="store_true", help="print only the errors")
    val.set_defaults(func=cmd_validate)
    p.set_defaults(func=lambda a: (p.print_help(), 2)[1])


def check(name_or_path: str):
    """Load a scenario and check the tables its users read at launch (``[aircraft]``,
    ``[aircraft.crlb]``); returns the scenario or raises ``ScenarioError`` naming file, section, key."""
    from larns.commands.crlb import crlb_settings
    from net.scenario import ScenarioError, load

    sc = load(name_or_path)
    if sc.aircraft:
        from aircraft.config import from_scenario

        try:
            from_scenario(sc)
        except (ValueError, TypeError) as e:
            raise ScenarioError(_aircraft_message(str(e)), file=sc.source) from None
    crlb_settings(sc)
    return sc


def _aircraft_message(error: str) -> str:
    """``aircraft/config.py``'s "unknown keys in [aircraft]: ['x']; known: [...]" as ``[aircraft] x: ...``."""
    m = re.match(r"unknown keys in \[([\w.]+)\]: \['([^']+)'[^\]]*\](?:; known: \[(.*)\])?$", error)
    if m is None:
        return f"[aircraft]: {error} (expected what docs/aircraft.md describes)"
    known = f"one of {m[3].replace(chr(39), '')}" if m[3] else "the keys of docs/aircraft.md"
    return f"[{m[1]}] {m[2]}: unknown key (expected {known})"


def cmd_list(args: argparse.Namespace) -> int:
    from net.scenario import packaged_names, read_toml, resolve

    names = packaged_names()
    width = max(len(n) for n in names)
    for n in names:
        raw = read_toml(resolve(n))
        print(f"{n:<{width}}  {raw.get('description', '')}")
    print(f"({len(names)} packaged scenarios; `larns scenario show NAME` for one, `--scenario FILE.toml` for "
          "your own)")
    return 0


def _fields(obj) -> str:
    return ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in asdict(obj).items())


def _tdma(tdma) -> str:
    """The plan: cycle and slot, and the distributed assignment's keys when it is on."""
    out = f"cycle_s {tdma.cycle_s:g}, slot_s {tdma.slot_s:g} ({tdma.slots_per_cycle} slots per cycle)"
    if tdma.distributed:
        out += f"; assignment distributed among {tdma.assigned_slots} slots (cycle_slots {tdma.cycle_slots})"
    return out


def _kv(table: dict) -> str:
    return ", ".join(f"{k} = {v!r}" for k, v in table.items())


def _link(lk) -> str:
    sel = f"station {lk.ids[0]}" if len(lk.ids) == 1 else f"stations {list(lk.ids)}"
    vals = {k: getattr(lk, k) for k in ("nlos_prob", "nlos_bias_m", "loss_prob", "bias_m")}
    return ", ".join([sel] + [f"{k} {v:g}" for k, v in vals.items() if v is not None])


def _fault(f) -> str:
    from net.scenario import FAULT_KEYS

    out = [f"kind {f.kind}", f"station {f.station}"]
    for k in FAULT_KEYS[f.kind]:
        v = getattr(f, k)
        if v is None:
            out.append(f"{k} (the scenario's)")
        else:
            out.append(f"{k} {list(v)}" if isinstance(v, tuple) else f"{k} {v:g}")
    return ", ".join(out)


def format_scenario(sc) -> str:
    """The resolved scenario as text: every value the emulator uses, defaults filled in."""
    joiners = f"; joining later: {', '.join(map(str, sc.join_ids))}" if sc.join_ids else ""
    lines = [
        f"file:        {sc.source or '(not from a file)'}",
        f"name:        {sc.name}",
        f"description: {sc.description}",
        f"seed:        {sc.seed}",
        f"stations:    {len(sc.ids)} (ids {sc.ids[0]}..{sc.ids[-1]}{joiners}); [frame] z_ref {sc.z_ref}",
        f"[tdma]       {_tdma(sc.tdma)}",
        f"[channel]    {_fields(replace(sc.channel, radio=None)).removesuffix(', radio None')}",
        f"[clock]      {_fields(sc.clock)}",
        f"[net]        {_fields(sc.net)}",
        f"[init]       sigma0_m {sc.sigma0_m:g}",
        f"[survey]     estimator {sc.estimator}, ranges_per_update {sc.ranges_per_update}",
    ]
    radio = getattr(sc.channel, "radio", None)
    if radio is not None:
        from net.tiles import tile_size_m

        keep = {k: v for k, v in asdict(replace(radio, terrain=None)).items()
                if k not in ("up", "origin_height_m", "terrain")}
        keep["tile_m"] = tile_size_m(radio)  # the wire's tiles (net/tiles.py), derived when not given
        lines.append("[radio]      " + ", ".join(f"{k} {v:g}" if isinstance(v, float) and not isinstance(v, bool)
                                                 else f"{k} {v}" for k, v in keep.items()))
        if radio.terrain is not None:
            lines.append("[radio]      " + radio.terrain.describe())
    if sc.site is not None:
        lines.append(f"[site]       origin {sc.site.lat_deg:.9f} deg, {sc.site.lon_deg:.9f} deg, "
                     f"{sc.site.h_m:.3f} m (WGS84); azimuth of +X {sc.site.azimuth_deg:g} deg")
    lines += [f"[[links]]    {_link(lk)}" for lk in sc.links] + [f"[[faults]]   {_fault(f)}" for f in sc.faults]
    if sc.aircraft:
        lines.append(f"[aircraft]   {_kv({k: v for k, v in sc.aircraft.items() if not isinstance(v, dict)})}")
        lines += [f"[aircraft.{k}] {_kv(v)}" for k, v in sc.aircraft.items() if isinstance(v, dict)]
    geo = sc.site.net_to_geodetic(sc.pos_m) if sc.site is not None else None
    lines.append("stations in the network frame, m" + (" (and on WGS84)" if geo else "") + ":")
    lines.append(f"{'id':>5} {'x':>12} {'y':>12} {'z':>10}" + (f" {'lat_deg':>15} {'lon_deg':>15} {'h_m':>9}" if geo else ""))
    for k, (sid, p) in enumerate(zip(sc.ids, sc.pos_m)):
        ll = f" {geo[0][k]:15.9f} {geo[1][k]:15.9f} {geo[2][k]:9.3f}" if geo else ""
        lines.append(f"{sid:>5} {p[0]:12.2f} {p[1]:12.2f} {p[2]:10.2f}{ll}"
                     + ("  (joins later)" if sid in sc.join_ids else ""))
    return "\n".join(lines)


def cmd_show(args: argparse.Namespace) -> int:
    print(format_scenario(check(args.name)))  # a bad file: one line and exit 2 (larns.cli.main)
    return 0


def _aircraft_summary(sc) -> str:
    if not sc.aircraft:
        return ""
    return f", aircraft {','.join(sc.aircraft['algos']) if 'algos' in sc.aircraft else '(default algos)'}"


def cmd_validate(args: argparse.Namespace) -> int:
    from net.scenario import ScenarioError

    bad = 0
    for f in args.files:
        try:
            sc = check(f)
        except ScenarioError as e:
            print(e, file=sys.stderr)
            bad += 1
            continue
        if not args.quiet:
            print(f"{f}: ok ({sc.name}: {len(sc.ids)} stations, {sc.tdma.slots_per_cycle} slots, "
                  f"estimator {sc.estimator}{_aircraft_summary(sc)})")
    return 2 if bad else 0
