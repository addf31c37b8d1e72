"""Scenario files (TOML): the emulated world - true station positions, TDMA timing, channel
parameters, initial-fix accuracy, network faults and the aircraft.

A scenario is data for the emulator shell. Estimators never see it (only the parts a real station
would know: its id, the TDMA plan, its nominal ranging accuracy and its coarse initial fix).

Format (see docs/scenarios.md for the full reference)::

    name = "seed000"
    description = "..."
    seed = 1                      # RNG seed of everything random in the world

    [frame]
    z_ref = 4                     # station id fixing the sign of +Z

    [layout]                      # either a random layout ...
    kind = "random"
    n = 10
    area_m = [2000.0, 2000.0, 80.0]
    min_separation_m = 100.0
    # ... or explicit stations:
    # [[stations]]
    # id = 1
    # pos_m = [0.0, 0.0, 0.0]     # physical coordinates; converted to the network frame

    [tdma]
    cycle_s = 1.0
    slot_s = 0.01

    [channel]
    sigma_d_m = 0.5               # two-way range noise (1 sigma)
    nlos_prob = 0.0
    nlos_bias_m = 0.0             # mean of the exponential positive NLOS bias
    loss_prob = 0.0
    clock_offset_s = 0.0          # sigma of per-station clock offsets
    clock_drift_ppm = 0.0         # sigma of per-station clock drifts
    turnaround_s = 0.001          # responder's fixed turnaround

    [clock]                       # station oscillators (net/clock.py); absent: perfect clocks
    model = "tcxo"                # preset: perfect | tcxo | ocxo | custom; keys below override it
    # offset_s = 1e-3             # sigma of the offset at the fleet epoch
    # freq_ppm = 2.0              # sigma of the fractional frequency offset
    # q_wf_s = 1e-20              # white frequency noise density
    # q_rw_per_s = 3e-22          # random-walk frequency noise density

    [net]                         # injected network faults (wire, not air)
    delay_s = 0.0
    jitter_s = 0.0
    loss_prob = 0.0
    dup_prob = 0.0

    [init]
    sigma0_m = 10.0               # coarse external fix, per coordinate; 0 -> no fix (trilaterate)

    [survey]
    estimator = "dmap"
    ranges_per_update = 3         # seed-ukf: l
"""

from __future__ import annotations

import importlib.resources
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from nav.geometry import to_network_frame

from .clock import ClockParams, clock_params


@dataclass(frozen=True)
class ChannelParams:
    sigma_d_m: float = 0.5
    nlos_prob: float = 0.0
    nlos_bias_m: float = 0.0
    loss_prob: float = 0.0
    clock_offset_s: float = 0.0
    clock_drift_ppm: float = 0.0
    turnaround_s: float = 0.001


@dataclass(frozen=True)
class NetFaults:
    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss_prob: float = 0.0
    dup_prob: float = 0.0


@dataclass(frozen=True)
class Tdma:
    cycle_s: float = 1.0
    slot_s: float = 0.01

    @property
    def slots_per_cycle(self) -> int:
        return int(round(self.cycle_s / self.slot_s))


@dataclass
class Scenario:
    """A loaded scenario. ``pos_m`` is (n, 3) in the network frame, rows ordered like ``ids``."""

    name: str
    description: str
    seed: int
    ids: list[int]
    pos_m: np.ndarray
    z_ref: int
    tdma: Tdma
    channel: ChannelParams
    net: NetFaults
    sigma0_m: float
    estimator: str
    ranges_per_update: int
    join_ids: list[int] = field(default_factory=list)  # stations that start later with --join
    aircraft: dict[str, Any] = field(default_factory=dict)
    raw: dict[str, Any] = field(default_factory=dict)
    clock: ClockParams = field(default_factory=ClockParams)  # station oscillators ([clock])
    links: list["LinkOverride"] = field(default_factory=list)  # per-link / per-station channel
    faults: list["StationFault"] = field(default_factory=list)  # [[faults]]: faulty or lying stations

    def index(self, station_id: int) -> int:
        return self.ids.index(station_id)

    def true_pos(self, station_id: int) -> np.ndarray:
        return self.pos_m[self.index(station_id)]

    @property
    def initial_ids(self) -> list[int]:
        return [i for i in self.ids if i not in self.join_ids]


def random_layout(
    rng: np.random.Generator, n: int, area_m: tuple[float, float, float], min_separation_m: float = 100.0
) -> np.ndarray:
    """Uniform random physical positions (n, 3) in a box, with a minimum horizontal separation."""
    pts: list[np.ndarray] = []
    for _ in range(100_000):
        p = rng.uniform(0.0, 1.0, 3) * np.asarray(area_m, dtype=float)
        if all(np.hypot(*(p[:2] - q[:2])) >= min_separation_m for q in pts):
            pts.append(p)
            if len(pts) == n:
                return np.array(pts)
    raise ValueError("could not place stations with that separation; lower min_separation_m")


def order_for_frame(pos_m: np.ndarray) -> np.ndarray:
    """Reorder random physical positions so the frame stations make a well-conditioned frame.

    Station 1: nearest the centroid's corner (the first point); station 2: the farthest point from 1;
    station 3: the point farthest from the line 1-2; station 4: the point highest above the plane of
    1-2-3 (so +Z points up). Returns an index permutation.
    """
    n = len(pos_m)
    idx = list(range(n))
    i1 = 0
    i2 = max((i for i in idx if i != i1), key=lambda i: np.linalg.norm(pos_m[i] - pos_m[i1]))
    ex = (pos_m[i2] - pos_m[i1]) / np.linalg.norm(pos_m[i2] - pos_m[i1])

    def off_line(i: int) -> float:
        v = pos_m[i] - pos_m[i1]
        return float(np.linalg.norm(v - ex * (v @ ex)))

    i3 = max((i for i in idx if i not in (i1, i2)), key=off_line)
    order = [i1, i2, i3]
    rest = [i for i in idx if i not in order]
    if rest:
        nrm = np.cross(pos_m[i2] - pos_m[i1], pos_m[i3] - pos_m[i1])
        nrm = nrm / np.linalg.norm(nrm) * (1.0 if nrm[2] >= 0 else -1.0)  # upward normal
        i4 = max(rest, key=lambda i: float((pos_m[i] - pos_m[i1]) @ nrm))
        order.append(i4)
        order += [i for i in rest if i != i4]
    return np.array(order)


def resolve(name_or_path: str | Path) -> Path:
    """A scenario path: an existing file, or the name of a packaged scenario (``seed000``)."""
    p = Path(name_or_path)
    if p.suffix == ".toml" and p.exists():
        return p
    if p.exists() and p.is_file():
        return p
    pkg = importlib.resources.files("net") / "scenarios" / f"{name_or_path}.toml"
    if pkg.is_file():
        return Path(str(pkg))
    raise FileNotFoundError(f"no scenario file or packaged scenario named {name_or_path!r}")


def load(name_or_path: str | Path, **overrides: Any) -> Scenario:
    """Load a scenario by name or path. ``overrides`` replace top-level keys of sections,
    e.g. ``load("seed000", channel={"sigma_d_m": 1.5}, layout={"n": 12}, seed=7)``."""
    with open(resolve(name_or_path), "rb") as f:
        raw = tomllib.load(f)
    for k, v in overrides.items():
        if isinstance(v, dict):
            raw.setdefault(k, {}).update(v)
        else:
            raw[k] = v
    return from_dict(raw)


def load_cli(name_or_path: str | Path, n_stations: int | None = None, **overrides: Any) -> Scenario:
    """:func:`load` as the processes' ``--scenario`` / ``--n-stations`` flags ask for it: ``n_stations``
    (if given and non-zero) sets the station count of a random layout (``[layout] n``)."""
    if n_stations:
        layout = dict(overrides.pop("layout", None) or {})
        layout["n"] = int(n_stations)
        overrides["layout"] = layout
    return load(name_or_path, **overrides)


def from_dict(raw: dict[str, Any]) -> Scenario:
    """The scenario of a parsed TOML document; an invalid entry raises :class:`ScenarioError` naming
    its key (e.g. ``[channel] sigma_d_m``, ``stations[2].pos_m``, ``faults[1].offset_m``)."""
    validate(raw)
    seed = int(raw.get("seed", 0))
    frame = raw.get("frame", {})
    z_ref = int(frame.get("z_ref", 4))
    if "stations" in raw:
        st = raw["stations"]
        ids = [int(s["id"]) for s in st]
        phys = np.array([[float(v) for v in s["pos_m"]] for s in st])
        join_ids = [int(s["id"]) for s in st if s.get("join", False)]
    else:
        lay = raw.get("layout", {})
        n = int(lay.get("n", 10))
        rng = np.random.default_rng(seed)
        phys = random_layout(rng, n, tuple(lay.get("area_m", (2000.0, 2000.0, 80.0))),
                             float(lay.get("min_separation_m", 100.0)))
        phys = phys[order_for_frame(phys)]
        ids = list(range(1, n + 1))
        join_ids = [int(i) for i in lay.get("join_ids", [])]
        joiners = int(lay.get("joiners", 0))
        if joiners:
            # newcomers from their own stream: the first n stations stay exactly where they were
            jr = np.random.default_rng([seed, 7])
            area = np.asarray(lay.get("area_m", (2000.0, 2000.0, 80.0)), dtype=float)
            sep = float(lay.get("min_separation_m", 100.0))
            extra: list[np.ndarray] = []
            while len(extra) < joiners:
                p = jr.uniform(0.0, 1.0, 3) * area
                if all(np.hypot(*(p[:2] - q[:2])) >= sep for q in list(phys) + extra):
                    extra.append(p)
            phys = np.vstack([phys, extra])
            ids += list(range(n + 1, n + joiners + 1))
            join_ids += list(range(n + 1, n + joiners + 1))
    if len(set(ids)) != len(ids) or min(ids) < 1:
        raise ValueError("station ids must be unique positive integers")
    order = np.argsort(ids)
    ids = [ids[i] for i in order]
    phys = phys[order]
    if ids[:3] != [1, 2, 3]:
        raise ValueError("stations 1, 2 and 3 must exist: they define the network frame")
    zi = ids.index(z_ref) if z_ref in ids else 3
    pos, _, _ = to_network_frame(phys, z_ref=zi)
    init = raw.get("init", {})
    survey = raw.get("survey", {})
    channel = ChannelParams(**raw.get("channel", {}))
    return Scenario(
        name=str(raw.get("name", "unnamed")),
        description=str(raw.get("description", "")),
        seed=seed,
        ids=ids,
        pos_m=pos,
        z_ref=z_ref,
        tdma=Tdma(**raw.get("tdma", {})),
        channel=channel,
        net=NetFaults(**raw.get("net", {})),
        sigma0_m=float(init.get("sigma0_m", 10.0)),
        estimator=str(survey.get("estimator", "dmap")),
        ranges_per_update=int(survey.get("ranges_per_update", 3)),
        join_ids=join_ids,
        aircraft=dict(raw.get("aircraft", {})),
        raw=raw,
        clock=_clock(raw, channel),
        links=parse_links(raw.get("links", []), ids),
        faults=parse_faults(raw.get("faults", []), ids),
    )


# ---------------------------------------------------------------- per-link channel and station faults
class ScenarioError(ValueError):
    """A scenario entry is invalid; the message names the key (e.g. ``faults[1].offset_m``)."""


@dataclass(frozen=True)
class LinkOverride:
    """``[[links]]``: channel of the links of one station (``station``) or of one pair (``stations``).

    Unset fields (None) keep the ``[channel]`` value. ``bias_m`` is a constant two-way range bias
    (half on each leg), e.g. a longer antenna cable; NLOS and loss act per leg like ``[channel]``.
    """

    ids: tuple[int, ...]
    nlos_prob: float | None = None
    nlos_bias_m: float | None = None
    loss_prob: float | None = None
    bias_m: float = 0.0

    def applies(self, a: int, b: int) -> bool:
        return (a in self.ids and b in self.ids) if len(self.ids) == 2 else self.ids[0] in (a, b)


FAULT_KEYS = {
    "liar": {"offset_m": "vec3", "from_s": "float"},
    "range_bias": {"bias_m": "float", "from_s": "float"},
    "clock_jump": {"jump_s": "float", "at_s": "float"},
    "bad_fix": {"offset_m": "vec3", "sigma0_m": "float"},
}
FAULT_OPTIONAL = {"from_s": 0.0, "at_s": 0.0}


@dataclass(frozen=True)
class StationFault:
    """``[[faults]]`` entry; applied in the station's shell (simulator and node alike), never in its
    estimator. ``liar``: broadcasts (nav, range answers) carry ``pos_m + offset_m`` from ``from_s``;
    ``range_bias``: every range of ``station`` is ``bias_m`` long from ``from_s``; ``clock_jump``: its
    clock steps by ``jump_s`` at true time ``at_s``; ``bad_fix``: its coarse fix is off by ``offset_m``
    while it claims ``sigma0_m`` (default: the scenario's)."""

    kind: str
    station: int
    offset_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    from_s: float = 0.0
    bias_m: float = 0.0
    jump_s: float = 0.0
    at_s: float = 0.0
    sigma0_m: float | None = None

    @property
    def onset_s(self) -> float:
        return self.at_s if self.kind == "clock_jump" else (0.0 if self.kind == "bad_fix" else self.from_s)


def _num(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ScenarioError(f"{where}: expected a finite number, got {v!r}")
    return float(v)


def _station(v: Any, where: str, ids: list[int]) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise ScenarioError(f"{where}: expected a station id (integer), got {v!r}")
    if v not in ids:
        raise ScenarioError(f"{where}: no station {v} in this scenario (ids {ids[0]}..{ids[-1]})")
    return v


def parse_faults(entries: Any, ids: list[int]) -> list[StationFault]:
    if not isinstance(entries, list):
        raise ScenarioError("faults: expected an array of tables ([[faults]])")
    out = []
    for i, e in enumerate(entries):
        w = f"faults[{i}]"
        if not isinstance(e, dict):
            raise ScenarioError(f"{w}: expected a table")
        kind = e.get("kind")
        if kind not in FAULT_KEYS:
            raise ScenarioError(f"{w}.kind: expected one of {sorted(FAULT_KEYS)}, got {kind!r}")
        if "station" not in e:
            raise ScenarioError(f"{w}.station: missing (the faulty station's id)")
        spec = FAULT_KEYS[kind]
        unknown = set(e) - set(spec) - {"kind", "station"}
        if unknown:
            raise ScenarioError(f"{w}.{sorted(unknown)[0]}: unknown key for kind {kind!r} "
                                f"(keys: kind, station, {', '.join(spec)})")
        kw: dict[str, Any] = {"kind": kind, "station": _station(e["station"], f"{w}.station", ids)}
        for key, typ in spec.items():
            if key not in e:
                if key in FAULT_OPTIONAL or (kind == "bad_fix" and key == "sigma0_m"):
                    continue
                raise ScenarioError(f"{w}.{key}: missing (required for kind {kind!r})")
            v = e[key]
            if typ == "vec3":
                if not isinstance(v, list) or len(v) != 3:
                    raise ScenarioError(f"{w}.{key}: expected 3 numbers [x, y, z] in metres, got {v!r}")
                kw[key] = tuple(_num(x, f"{w}.{key}") for x in v)
            else:
                kw[key] = _num(v, f"{w}.{key}")
        if kw.get("sigma0_m", 1.0) is not None and kw.get("sigma0_m", 1.0) < 0:
            raise ScenarioError(f"{w}.sigma0_m: must be >= 0")
        out.append(StationFault(**kw))
    return out


def parse_links(entries: Any, ids: list[int]) -> list[LinkOverride]:
    if not isinstance(entries, list):
        raise ScenarioError("links: expected an array of tables ([[links]])")
    out = []
    for i, e in enumerate(entries):
        w = f"links[{i}]"
        if not isinstance(e, dict):
            raise ScenarioError(f"{w}: expected a table")
        unknown = set(e) - {"station", "stations", "nlos_prob", "nlos_bias_m", "loss_prob", "bias_m"}
        if unknown:
            raise ScenarioError(f"{w}.{sorted(unknown)[0]}: unknown key (keys: station or stations, "
                                "nlos_prob, nlos_bias_m, loss_prob, bias_m)")
        if ("station" in e) == ("stations" in e):
            raise ScenarioError(f"{w}.station: give exactly one of station = id or stations = [a, b]")
        if "station" in e:
            sel = (_station(e["station"], f"{w}.station", ids),)
        else:
            v = e["stations"]
            if not isinstance(v, list) or len(v) != 2 or v[0] == v[1]:
                raise ScenarioError(f"{w}.stations: expected two different station ids [a, b], got {v!r}")
            sel = tuple(_station(x, f"{w}.stations", ids) for x in v)
        kw: dict[str, Any] = {}
        for key in ("nlos_prob", "loss_prob"):
            if key in e:
                kw[key] = _num(e[key], f"{w}.{key}")
                if not 0.0 <= kw[key] <= 1.0:
                    raise ScenarioError(f"{w}.{key}: must be a probability in [0, 1]")
        for key in ("nlos_bias_m", "bias_m"):
            if key in e:
                kw[key] = _num(e[key], f"{w}.{key}")
        if kw.get("nlos_bias_m", 0.0) < 0:
            raise ScenarioError(f"{w}.nlos_bias_m: must be >= 0")
        out.append(LinkOverride(sel, **kw))
    return out


# ---------------------------------------------------------------- validation of the other sections
def _clock(raw: dict, channel: ChannelParams) -> ClockParams:
    try:
        return clock_params(raw.get("clock"), channel.clock_offset_s, channel.clock_drift_ppm)
    except ValueError as e:  # net/clock.py names the key ("[clock] model: ...")
        raise ScenarioError(str(e)) from None


_NONNEG, _PROB, _POS = "must be >= 0", "must be a probability in [0, 1]", "must be > 0"
_SECTION_RULES: dict[str, tuple[type, dict[str, str]]] = {
    "tdma": (Tdma, {"cycle_s": _POS, "slot_s": _POS}),
    "channel": (ChannelParams, {"sigma_d_m": _NONNEG, "nlos_prob": _PROB, "nlos_bias_m": _NONNEG,
                                "loss_prob": _PROB, "clock_offset_s": _NONNEG, "clock_drift_ppm": _NONNEG,
                                "turnaround_s": _NONNEG}),
    "net": (NetFaults, {"delay_s": _NONNEG, "jitter_s": _NONNEG, "loss_prob": _PROB, "dup_prob": _PROB}),
    "init": (None, {"sigma0_m": _NONNEG}),
}
_LAYOUT_KEYS = ("kind", "n", "area_m", "min_separation_m", "join_ids", "joiners")
_SURVEY_KEYS = ("estimator", "ranges_per_update")


def _table(raw: dict, key: str) -> dict:
    v = raw.get(key, {})
    if not isinstance(v, dict):
        raise ScenarioError(f"[{key}]: expected a table, got {v!r}")
    return v


def _int(v: Any, where: str, low: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        raise ScenarioError(f"{where}: expected an integer >= {low}, got {v!r}")
    return v


def _known(tab: dict, where: str, keys: Any) -> None:
    unknown = sorted(set(tab) - set(keys))
    if unknown:
        raise ScenarioError(f"{where} {unknown[0]}: unknown key; keys are {', '.join(sorted(keys))}")


def _check_rule(v: float, where: str, rule: str) -> None:
    ok = {_NONNEG: v >= 0.0, _PROB: 0.0 <= v <= 1.0, _POS: v > 0.0}[rule]
    if not ok:
        raise ScenarioError(f"{where}: {rule}, got {v!r}")


def _validate_params(raw: dict) -> None:
    for key, (cls, rules) in _SECTION_RULES.items():
        tab = _table(raw, key)
        _known(tab, f"[{key}]", [f.name for f in fields(cls)] if cls is not None else rules)
        for k, v in tab.items():
            if k in rules:
                _check_rule(_num(v, f"[{key}] {k}"), f"[{key}] {k}", rules[k])
    tdma = _table(raw, "tdma")
    if _num(tdma.get("slot_s", 0.01), "[tdma] slot_s") > _num(tdma.get("cycle_s", 1.0), "[tdma] cycle_s"):
        raise ScenarioError("[tdma] slot_s: longer than cycle_s")


def _validate_layout(raw: dict) -> None:
    lay = _table(raw, "layout")
    _known(lay, "[layout]", _LAYOUT_KEYS)
    if "n" in lay:
        _int(lay["n"], "[layout] n", 3)
    if "joiners" in lay:
        _int(lay["joiners"], "[layout] joiners", 0)
    if "min_separation_m" in lay:
        _check_rule(_num(lay["min_separation_m"], "[layout] min_separation_m"), "[layout] min_separation_m", _NONNEG)
    area = lay.get("area_m", (1.0, 1.0, 1.0))
    if not isinstance(area, (list, tuple)) or len(area) != 3:
        raise ScenarioError(f"[layout] area_m: expected 3 numbers [x, y, z] in metres, got {area!r}")
    for i, v in enumerate(area):
        _check_rule(_num(v, f"[layout] area_m[{i}]"), f"[layout] area_m[{i}]", _NONNEG)
    join = lay.get("join_ids", [])
    if not isinstance(join, list):
        raise ScenarioError(f"[layout] join_ids: expected a list of station ids, got {join!r}")
    for i, v in enumerate(join):
        _int(v, f"[layout] join_ids[{i}]", 1)


def _validate_stations(raw: dict) -> None:
    st = raw.get("stations")
    if st is None:
        return
    if not isinstance(st, list) or not st:
        raise ScenarioError("stations: expected a non-empty array of tables ([[stations]])")
    for i, e in enumerate(st):
        w = f"stations[{i}]"
        if not isinstance(e, dict):
            raise ScenarioError(f"{w}: expected a table")
        if "id" not in e:
            raise ScenarioError(f"{w}.id: missing")
        _int(e["id"], f"{w}.id", 1)
        pos = e.get("pos_m")
        if pos is None:
            raise ScenarioError(f"{w}.pos_m: missing (physical coordinates [x, y, z], m)")
        if not isinstance(pos, list) or len(pos) != 3:
            raise ScenarioError(f"{w}.pos_m: expected 3 numbers [x, y, z] in metres, got {pos!r}")
        for j, v in enumerate(pos):
            _num(v, f"{w}.pos_m[{j}]")
        if not isinstance(e.get("join", False), bool):
            raise ScenarioError(f"{w}.join: expected true or false, got {e['join']!r}")


def validate(raw: dict[str, Any]) -> None:
    """Check the sections :func:`from_dict` reads (``[[faults]]`` and ``[[links]]`` are checked by their
    parsers); raises :class:`ScenarioError` naming the first bad key."""
    if not isinstance(raw, dict):
        raise ScenarioError(f"scenario: expected a table, got {type(raw).__name__}")
    if "seed" in raw:
        _int(raw["seed"], "seed", 0)
    _validate_params(raw)
    _validate_layout(raw)
    _validate_stations(raw)
    frame = _table(raw, "frame")
    _known(frame, "[frame]", ("z_ref",))
    if "z_ref" in frame:
        _int(frame["z_ref"], "[frame] z_ref", 1)
    survey = _table(raw, "survey")
    _known(survey, "[survey]", _SURVEY_KEYS)
    if "estimator" in survey and not isinstance(survey["estimator"], str):
        raise ScenarioError(f"[survey] estimator: expected a name, got {survey['estimator']!r}")
    if "ranges_per_update" in survey:
        _int(survey["ranges_per_update"], "[survey] ranges_per_update", 1)
