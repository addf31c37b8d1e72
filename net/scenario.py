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
    # ... or, with or without [site], on WGS84:
    # lat_deg = 48.8566
    # lon_deg = 2.3522
    # h_m = 35.0                  # ellipsoidal height (default 0)

    [site]                        # optional: the field on the Earth (nav/site.py)
    origin = [48.8566, 2.3522, 35.0]  # lat deg, lon deg, h m of the physical frame's origin
    azimuth_deg = 90.0            # direction of physical +X, clockwise from north (90: +X east)
    # stations_geojson = "stations.geojson"  # Point features with an "id" property, instead of [[stations]]

    [tdma]
    cycle_s = 1.0
    slot_s = 0.01
    # ranging = "poll"            # protocol v2 (docs/protocol.md): one poll per slot, every member replies
    # reply_spacing_s = 0.0005    # ... in its sub-slot turnaround_s + k reply_spacing_s after the poll
    # frame_s = 0.0001            # ... one frame on air; guard_s = 0.0001 the slot-timing margin

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
    datum = "founders"            # or "field": the converged stations take the frame over

Everything is checked when the file is loaded (:func:`load`): an invalid file raises one
:class:`ScenarioError` that names the file, the section and the key, e.g.
``typo.toml: [survey] estimator: unknown estimator 'kalman' (expected one of dmap, ...)``; the
``larns`` CLI prints that line and exits 2 (``larns scenario validate FILE`` checks a file).
"""

from __future__ import annotations

import difflib
import importlib.resources
import re
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from nav.geometry import to_network_frame
from nav.site import Site

from .clock import PRESETS, ClockParams, clock_params
from .radio import RadioParams
from .radio import parse as parse_radio
from .sidefile import read_beside
from .slotplan import check_slot_plan


class ScenarioError(ValueError):
    """An invalid scenario. The message starts with the key it is about (``[channel] sigma_d_m: ...``,
    ``stations[2].pos_m[1]: ...``, ``faults[1].offset_m: ...``, ``seed: ...`` for a top-level key) and
    ends with what was expected; ``file`` is the file it came from (set by :func:`load`), and then
    ``str()`` is the one line ``FILE: [section] key: what is wrong (expected ...)``."""

    _WHERE = re.compile(r"^(?:\[(?P<section>[^\]]+)\](?: (?P<key>[^:\s]+))?"
                        r"|(?P<array>\w+\[\d+\])(?:\.(?P<akey>[^:\s]+))?"
                        r"|(?P<top>[\w-]+)):")

    def __init__(self, message: str, file: str | Path | None = None):
        super().__init__(message)
        self.message = message
        self.file = None if file is None else str(file)

    def __str__(self) -> str:
        return f"{self.file}: {self.message}" if self.file else self.message

    @property
    def section(self) -> str:
        """The section of the entry (``channel``, ``stations[2]``, ``aircraft.crlb``); "" at the top level."""
        m = self._WHERE.match(self.message)
        return "" if m is None else (m["section"] or m["array"] or "")

    @property
    def key(self) -> str:
        """The key of the entry (``sigma_d_m``, ``pos_m[1]``, ``seed``); "" for a whole section."""
        m = self._WHERE.match(self.message)
        return "" if m is None else (m["key"] or m["akey"] or m["top"] or "")


class ScenarioNotFound(ScenarioError, FileNotFoundError):
    """No such scenario file nor packaged scenario; the message lists the packaged names."""


@dataclass(frozen=True)
class ChannelParams:
    sigma_d_m: float = 0.5
    nlos_prob: float = 0.0
    nlos_bias_m: float = 0.0
    loss_prob: float = 0.0
    clock_offset_s: float = 0.0
    clock_drift_ppm: float = 0.0
    turnaround_s: float = 0.001
    # the [radio] section (net/radio.py), in the network frame; None: every station hears every other
    # at any distance with the noise sigma_d_m
    radio: RadioParams | None = None


@dataclass(frozen=True)
class NetFaults:
    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss_prob: float = 0.0
    dup_prob: float = 0.0


@dataclass(frozen=True)
class Tdma:
    """``[tdma]``. ``assignment``: "fixed" (station ``id`` owns slot ``id - 1``, one slot per station)
    or "distributed" (each station picks a slot free in its two-hop view, ``stations/slots.py``, among
    the first ``cycle_slots`` slots of the cycle; 0: all of them; docs/slots.md).

    ``ranging`` (issue 31, docs/protocol.md "Protocol v2"): "addressed" (one ``range_req`` to one peer
    per slot, the default) or "poll" (one ``poll`` answered by every member in its reply sub-slot,
    ``turnaround_s + k reply_spacing_s`` after the poll; ``frame_s`` one frame's time on air,
    ``guard_s`` the slot-timing margin - the loader checks that poll, replies and final fit, rule V8)."""

    cycle_s: float = 1.0
    slot_s: float = 0.01
    assignment: str = "fixed"
    cycle_slots: int = 0
    ranging: str = "addressed"
    reply_spacing_s: float = 0.0005
    frame_s: float = 0.0001
    guard_s: float = 0.0001

    @property
    def poll(self) -> bool:
        return self.ranging == "poll"

    @property
    def slots_per_cycle(self) -> int:
        return int(round(self.cycle_s / self.slot_s))

    @property
    def distributed(self) -> bool:
        return self.assignment == "distributed"

    @property
    def assigned_slots(self) -> int:
        """Slots the distributed assignment picks among (``cycle_slots``, or the whole cycle)."""
        return self.cycle_slots or self.slots_per_cycle


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
    source: str = ""  # the file it was loaded from ("" when built from a dict)
    site: Site | None = None  # [site]: the physical frame on WGS84, tied to the network frame
    # [survey] datum: "founders" (stations 1-3 hold the frame throughout) or "field" (the converged
    # stations take it over: docs/architecture.md, "The frame datum"; opt-in while its known height
    # defect stands, docs/survey.md)
    datum: str = "founders"

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
    raise ScenarioError(f"[layout] min_separation_m: no room for {n} stations {min_separation_m:g} m apart "
                        "(expected a smaller min_separation_m, fewer stations or a larger area_m)")


def order_for_frame(pos_m: np.ndarray, within_m: float | None = None) -> np.ndarray:
    """Reorder random physical positions so the frame stations make a well-conditioned frame.

    Station 1: the first point; station 2: the farthest point from 1; station 3: the point farthest
    from the line 1-2; station 4: the point highest above the plane of 1-2-3 (so +Z points up).
    ``within_m``: :func:`order_founders_near`. Returns an index permutation.
    """
    if within_m is not None:
        return order_founders_near(pos_m, within_m)
    n = len(pos_m)
    idx = list(range(n))
    i1 = 0
    i2 = max((i for i in idx if i != i1), key=lambda i: np.linalg.norm(pos_m[i] - pos_m[i1]))
    ex = (pos_m[i2] - pos_m[i1]) / np.linalg.norm(pos_m[i2] - pos_m[i1])

    def off_line(i: int) -> float:
        v = pos_m[i] - pos_m[i1]
        return float(np.linalg.norm(v - ex * (v @ ex)))

    i3 = max((i for i in idx if i not in (i1, i2)), key=off_line)
    return _with_z_ref(pos_m, [i1, i2, i3], [i for i in idx if i not in (i1, i2, i3)])


def _with_z_ref(pos_m: np.ndarray, founders: list[int], candidates: list[int]) -> np.ndarray:
    """The permutation: the founders, then station 4 the candidate highest above their plane, then the rest."""
    i1, i2, i3 = founders
    order = list(founders)
    if candidates:
        nrm = np.cross(pos_m[i2] - pos_m[i1], pos_m[i3] - pos_m[i1])
        nrm = nrm / np.linalg.norm(nrm) * (1.0 if nrm[2] >= 0 else -1.0)  # upward normal
        order.append(max(candidates, key=lambda i: float((pos_m[i] - pos_m[i1]) @ nrm)))
    order += [i for i in range(len(pos_m)) if i not in order]
    return np.array(order)


def order_founders_near(pos_m: np.ndarray, within_m: float) -> np.ndarray:
    """:func:`order_for_frame` for a field larger than a radio link: the founders must hear each other.

    Station 1: the first point with at least three others within ``within_m`` (horizontally); stations
    2 and 3: the pair of those, within ``within_m`` of each other, that makes the widest triangle with
    1 (largest horizontal area: the frame's plane and axes as well conditioned as the layout allows),
    2 the farther from 1; station 4: the point within ``within_m`` of 1 and 2 (else of 1) highest
    above the plane of 1-2-3. Then 1 and 2 swap if the tetrahedron 1-2-3-4 is negatively oriented, so
    that station 3 lies on the left of 1 -> 2 seen from station 4's side: the handedness that stations
    without a coarse fix assume (ranges cannot tell a field from its mirror image; docs/survey.md).
    """
    P = np.asarray(pos_m, float)
    d_h = np.hypot(P[:, None, 0] - P[None, :, 0], P[:, None, 1] - P[None, :, 1])
    near = d_h <= within_m
    np.fill_diagonal(near, False)
    i1 = int(np.argmax(near.sum(axis=1) >= 3))
    cand1 = [int(i) for i in np.flatnonzero(near[i1])]
    pairs = [(a, b) for a in cand1 for b in cand1 if a < b and near[a, b]]
    if len(cand1) < 3 or not pairs:
        raise ScenarioError(f"[layout] founders_within_m: no three stations within {within_m:g} m of each other "
                            "(expected a larger founders_within_m or a denser layout)")

    def area(pair: tuple[int, int]) -> float:
        u, v = P[pair[0], :2] - P[i1, :2], P[pair[1], :2] - P[i1, :2]
        return abs(float(u[0] * v[1] - u[1] * v[0]))

    a, b = max(pairs, key=area)
    i2, i3 = (a, b) if d_h[i1, a] >= d_h[i1, b] else (b, a)
    z_cand = [i for i in cand1 if i not in (i2, i3) and near[i2, i]] or [i for i in cand1 if i not in (i2, i3)]
    order = _with_z_ref(P, [i1, i2, i3], z_cand)
    if np.linalg.det(P[order[1:4]] - P[order[0]]) < 0.0:
        order[[0, 1]] = order[[1, 0]]
    return order


def packaged_names() -> list[str]:
    """Names of the packaged scenarios (``net/scenarios/*.toml``), sorted."""
    folder = importlib.resources.files("net") / "scenarios"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def resolve(name_or_path: str | Path) -> Path:
    """A scenario path: an existing file, or the name of a packaged scenario (``seed000``); else
    :class:`ScenarioNotFound` (a ``FileNotFoundError`` too) listing the packaged names."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    pkg = importlib.resources.files("net") / "scenarios" / f"{name_or_path}.toml"
    if pkg.is_file():
        return Path(str(pkg))
    raise ScenarioNotFound("no such file, nor a packaged scenario of that name (expected a TOML file or "
                           f"one of {', '.join(packaged_names())})", file=name_or_path)


_HEADER = re.compile(r"^\s*(\[\[?[^\[\]]+\]\]?)\s*(#.*)?$")
_KEYLINE = re.compile(r"^\s*([A-Za-z0-9_.\"'-]+)\s*=")


def _syntax_message(text: str, error: str) -> str:
    """A TOML syntax error as ``[section] key: TOML syntax error at line L, column C: ...``: the section
    is the last table header above the line, the key the one the line assigns (if any)."""
    at = re.search(r"\(at line (\d+), column (\d+)\)\s*$", error)
    reason = re.sub(r"\s*\(at [^)]*\)\s*$", "", error)
    lines = text.splitlines()
    line = int(at[1]) if at else len(lines)
    position = f"line {line}, column {at[2]}" if at else f"the end of the file (line {line})"
    headers = [m[1] for m in map(_HEADER.match, lines[:line - 1]) if m]
    key = _KEYLINE.match(lines[line - 1]) if 0 < line <= len(lines) else None
    where = " ".join(x for x in (headers[-1] if headers else "", key[1] if key else "") if x)
    if not key and 0 < line <= len(lines) and lines[line - 1].lstrip().startswith("["):
        where = lines[line - 1].strip()  # the broken table header itself
    return f"{where + ': ' if where else ''}TOML syntax error at {position}: {reason} (expected valid TOML)"


def read_toml(path: str | Path) -> dict[str, Any]:
    """The parsed TOML document of a scenario file; :class:`ScenarioError` (naming the file) if it cannot
    be read or is not TOML (syntax errors give line, column, section and key)."""
    try:
        data = Path(path).read_bytes()
    except OSError as e:
        raise ScenarioError(f"cannot read the file: {e.strerror or e} (expected a readable TOML file)",
                            file=path) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ScenarioError(f"not UTF-8 text (byte {e.start}; expected a TOML file)", file=path) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ScenarioError(_syntax_message(text, str(e)), file=path) from None


def load(name_or_path: str | Path, **overrides: Any) -> Scenario:
    """Load a scenario by name or path. ``overrides`` replace top-level keys of sections,
    e.g. ``load("seed000", channel={"sigma_d_m": 1.5}, layout={"n": 12}, seed=7)``. Any problem raises
    :class:`ScenarioError` naming the file, section and key."""
    path = resolve(name_or_path)
    raw = read_toml(path)
    for k, v in overrides.items():
        if isinstance(v, dict) and isinstance(raw.get(k, {}), dict):
            raw.setdefault(k, {}).update(v)
        else:
            raw[k] = v
    try:
        scn = from_dict(raw, base_dir=path.parent)
    except ScenarioError as e:
        e.file = e.file or str(path)
        raise
    scn.source = str(path)
    return scn


def load_cli(name_or_path: str | Path, n_stations: int | None = None, **overrides: Any) -> Scenario:
    """:func:`load` as the processes' ``--scenario`` / ``--n-stations`` flags ask for it: ``n_stations``
    (if given and non-zero) sets the station count of a random layout (``[layout] n``)."""
    if n_stations:
        layout = dict(overrides.pop("layout", None) or {})
        layout["n"] = int(n_stations)
        overrides["layout"] = layout
    return load(name_or_path, **overrides)


def _explicit_stations(raw: dict[str, Any]) -> tuple[list[int], np.ndarray, list[int], list[str]]:
    """``[[stations]]``: ids, physical positions, joiners, and where each one is written."""
    st = raw["stations"]
    ids = [int(s["id"]) for s in st]
    phys = np.array([[float(v) for v in s["pos_m"]] for s in st])  # lat/lon ones: converted by _place_on_site
    join_ids = [int(s["id"]) for s in st if s.get("join", False)]
    return ids, phys, join_ids, [f"stations[{k}]" for k in range(len(st))]


def _random_stations(raw: dict[str, Any], seed: int) -> tuple[list[int], np.ndarray, list[int], list[str]]:
    """``[layout]``: ids, physical positions (frame stations first), joiners, and where each comes from."""
    lay = raw.get("layout", {})
    n = int(lay.get("n", 10))
    area = tuple(float(v) for v in lay.get("area_m", (2000.0, 2000.0, 80.0)))
    sep = float(lay.get("min_separation_m", 100.0))
    rng = np.random.default_rng(seed)
    phys = random_layout(rng, n, area, sep)
    within = lay.get("founders_within_m")
    phys = phys[order_for_frame(phys, None if within is None else float(within))]
    ids = list(range(1, n + 1))
    join_ids = [int(i) for i in lay.get("join_ids", [])]
    joiners = int(lay.get("joiners", 0))
    if joiners:
        # newcomers from their own stream: the first n stations stay exactly where they were
        jr = np.random.default_rng([seed, 7])
        extra: list[np.ndarray] = []
        for _ in range(100_000):
            if len(extra) == joiners:
                break
            p = jr.uniform(0.0, 1.0, 3) * np.asarray(area)
            if all(np.hypot(*(p[:2] - q[:2])) >= sep for q in list(phys) + extra):
                extra.append(p)
        else:
            raise ScenarioError(f"[layout] joiners: no room for {joiners} more stations {sep:g} m apart "
                                "(expected fewer joiners, a smaller min_separation_m or a larger area_m)")
        phys = np.vstack([phys, extra])
        ids += list(range(n + 1, n + joiners + 1))
        join_ids += list(range(n + 1, n + joiners + 1))
    return ids, phys, join_ids, ["[layout] n"] * n + ["[layout] joiners"] * joiners


def _check_ids(raw: dict[str, Any], ids: list[int], join_ids: list[int], where: list[str]) -> None:
    """Unique ids, the frame stations 1-3 present, every id a slot of the TDMA cycle, joiners known."""
    for k, i in enumerate(ids):
        if i in ids[:k]:
            raise ScenarioError(f"{where[k]}.id: station {i} appears twice (expected unique station ids)")
    if not {1, 2, 3} <= set(ids):
        raise ScenarioError(f"stations: ids {sorted(ids)} (expected stations 1, 2 and 3: they define the "
                            "network frame)")
    tdma = Tdma(**raw.get("tdma", {}))
    slots, top = tdma.slots_per_cycle, max(ids)
    if top > slots and not tdma.distributed:  # a distributed assignment: any number of stations
        w = where[ids.index(top)]
        w = f"{w}.id" if w.startswith("stations[") else w
        raise ScenarioError(f"{w}: station {top} needs slot {top}, but the TDMA cycle has {slots} slots "
                            f"([tdma] cycle_s {tdma.cycle_s:g} / slot_s {tdma.slot_s:g}) (expected station "
                            f"ids <= {slots}, or a longer cycle_s or shorter slot_s)")
    for k, j in enumerate(raw.get("layout", {}).get("join_ids", []) if "stations" not in raw else []):
        if j not in ids:
            raise ScenarioError(f"[layout] join_ids[{k}]: no station {j} (expected ids 1..{max(ids)})")


COINCIDENT_M = 1e-3  # stations closer than this are one place
COLLINEAR_FRACTION = 1e-3  # station 3 nearer the line 1-2 than this fraction of |1-2|: no frame


def _check_geometry(ids: list[int], phys: np.ndarray, where: dict[int, str]) -> None:
    """No two stations in one place; stations 1, 2, 3 (the frame) not on one line. ``phys`` in id order."""
    d = np.linalg.norm(phys[:, None, :] - phys[None, :, :], axis=-1)
    close = np.argwhere(np.triu(d < COINCIDENT_M, k=1))
    if len(close):
        a, b = (ids[int(i)] for i in close[0])
        w = where[b] + (".pos_m" if where[b].startswith("stations[") else "")
        raise ScenarioError(f"{w}: station {b} is at the position of station {a} (expected stations at "
                            f"least {COINCIDENT_M * 1e3:g} mm apart)")
    base = phys[1] - phys[0]
    v = phys[2] - phys[0]
    off_m = float(np.linalg.norm(v - base * (v @ base) / (base @ base)))
    if off_m < COLLINEAR_FRACTION * float(np.linalg.norm(base)):
        w = where[3] + (".pos_m" if where[3].startswith("stations[") else "")
        raise ScenarioError(f"{w}: stations 1, 2 and 3 are collinear (station 3 is {off_m:.3g} m off the "
                            f"line 1-2; expected at least {COLLINEAR_FRACTION:.1%} of the 1-2 distance, "
                            f"{COLLINEAR_FRACTION * float(np.linalg.norm(base)):.3g} m: they define the "
                            "network frame)")


# ---------------------------------------------------------------- [site]: the field on WGS84
_GEO_KEYS = ("lat_deg", "lon_deg", "h_m")
_SITE_KEYS = ("origin", "azimuth_deg", "stations_geojson")


def _lat_lon_h(lat: Any, lon: Any, h: Any, where: tuple[str, str, str]) -> tuple[float, float, float]:
    lat, lon, h = _num(lat, where[0]), _num(lon, where[1]), _num(h, where[2])
    if not -90.0 <= lat <= 90.0:
        raise ScenarioError(f"{where[0]}: got {lat!r} (expected a latitude in degrees, -90..90)")
    if not -180.0 <= lon <= 180.0:
        raise ScenarioError(f"{where[1]}: got {lon!r} (expected a longitude in degrees, -180..180)")
    return lat, lon, h


def _geodetic(e: dict, w: str) -> tuple[float, float, float]:
    """A ``[[stations]]`` entry's ``lat_deg``, ``lon_deg``, ``h_m`` (default 0), checked."""
    for k in ("lat_deg", "lon_deg"):
        if k not in e:
            raise ScenarioError(f"{w}.{k}: missing (expected lat_deg and lon_deg in degrees, h_m in metres, "
                                "or pos_m)")
    return _lat_lon_h(e["lat_deg"], e["lon_deg"], e.get("h_m", 0.0), (f"{w}.lat_deg", f"{w}.lon_deg", f"{w}.h_m"))


def _validate_site(raw: dict) -> None:
    site = _table(raw, "site")
    _known(site, "[site]", _SITE_KEYS)
    if "origin" in site:
        o = site["origin"]
        if not isinstance(o, list) or len(o) != 3:
            raise ScenarioError(f"[site] origin: got {o!r} (expected [lat_deg, lon_deg, h_m])")
        _lat_lon_h(*o, ("[site] origin[0]", "[site] origin[1]", "[site] origin[2]"))
    if "azimuth_deg" in site:
        _num(site["azimuth_deg"], "[site] azimuth_deg")
    if "stations_geojson" in site:
        f = site["stations_geojson"]
        if not isinstance(f, str) or not f:
            raise ScenarioError(f"[site] stations_geojson: got {f!r} (expected the path of a GeoJSON file)")
        if "stations" in raw:
            raise ScenarioError("[site] stations_geojson: both a GeoJSON file and [[stations]] (expected one of "
                                "them)")


def _geojson_stations(name: str, base_dir: Path | None) -> list[dict]:
    """``[site] stations_geojson``: the stations of a GeoJSON FeatureCollection of Point features
    (``[lon, lat]`` or ``[lon, lat, h]``, properties ``id`` and optionally ``join``) as
    ``[[stations]]`` entries with ``lat_deg`` / ``lon_deg`` / ``h_m``."""
    import json

    w = "[site] stations_geojson"
    path, doc = read_beside(name, base_dir, w, json.loads, "JSON", "a readable GeoJSON file, relative to the scenario file",
                            "a GeoJSON FeatureCollection", ScenarioError)
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection" or not isinstance(doc.get("features"), list):
        raise ScenarioError(f"{w}: {path}: not a FeatureCollection (expected a GeoJSON FeatureCollection of "
                            "Point features)")
    out = [_geojson_station(f, f"{w}: {path}: features[{i}]") for i, f in enumerate(doc["features"])]
    if not out:
        raise ScenarioError(f"{w}: {path}: no features (expected one Point feature per station)")
    return out


def _geojson_station(f: Any, fw: str) -> dict[str, Any]:
    """One GeoJSON Point feature as a ``[[stations]]`` entry; ``fw`` names it in errors."""
    geom = f.get("geometry") if isinstance(f, dict) else None
    if not isinstance(geom, dict) or geom.get("type") != "Point":
        raise ScenarioError(f"{fw}.geometry: got {geom!r:.60} (expected a Point)")
    c = geom.get("coordinates")
    if not isinstance(c, list) or len(c) not in (2, 3):
        raise ScenarioError(f"{fw}.geometry.coordinates: got {c!r} (expected [lon, lat] or [lon, lat, h])")
    props = f.get("properties") or {}
    sid = props.get("id") if isinstance(props, dict) else None
    if isinstance(sid, bool) or not isinstance(sid, int) or sid < 1:
        raise ScenarioError(f"{fw}.properties.id: got {sid!r} (expected the station id, an integer >= 1)")
    lat, lon, h = _lat_lon_h(c[1], c[0], c[2] if len(c) == 3 else 0.0,
                             (f"{fw}.coordinates[1]", f"{fw}.coordinates[0]", f"{fw}.coordinates[2]"))
    e: dict[str, Any] = {"id": sid, "lat_deg": lat, "lon_deg": lon, "h_m": h}
    if "join" in props:
        if not isinstance(props["join"], bool):
            raise ScenarioError(f"{fw}.properties.join: got {props['join']!r} (expected true or false)")
        e["join"] = props["join"]
    return e


def _place_on_site(raw: dict, base_dir: Path | None) -> tuple[dict, Site | None]:
    """``[site]`` and stations given on WGS84: the site (without its network tie yet) and the document
    with every station in physical coordinates (``pos_m``, the site's field frame), so the rest of the
    emulator reads one form. Without ``[site]`` origin, the lowest-id station's position is the origin."""
    site_t = dict(raw.get("site", {}))
    stations = raw.get("stations")
    if "stations_geojson" in site_t:
        stations = _geojson_stations(site_t.pop("stations_geojson"), base_dir)
    geo = [e for e in stations or [] if "lat_deg" in e]
    if not site_t and not geo:
        return raw, None
    if "origin" in site_t:
        origin = tuple(float(v) for v in site_t["origin"])
    elif geo and len(geo) < len(stations):
        raise ScenarioError("[site] origin: missing (expected [lat_deg, lon_deg, h_m] when stations mix pos_m "
                            "and lat_deg/lon_deg)")
    elif geo:
        first = min(geo, key=lambda e: int(e["id"]))
        origin = (float(first["lat_deg"]), float(first["lon_deg"]), float(first.get("h_m", 0.0)))
    else:
        raise ScenarioError("[site] origin: missing (expected [lat_deg, lon_deg, h_m] of the field's origin)")
    site = Site(*origin, azimuth_deg=float(site_t.get("azimuth_deg", 90.0)))
    out = dict(raw)
    out["site"] = {"origin": list(origin), "azimuth_deg": site.azimuth_deg}
    if geo:
        placed = []
        for e in stations:
            if "lat_deg" in e:
                p = site.geodetic_to_frame(e["lat_deg"], e["lon_deg"], e.get("h_m", 0.0))
                e = {**{k: v for k, v in e.items() if k not in _GEO_KEYS}, "pos_m": [float(v) for v in p]}
            placed.append(e)
        out["stations"] = placed
    elif stations is not None:
        out["stations"] = stations
    return out, site


def from_dict(raw: dict[str, Any], base_dir: str | Path | None = None) -> Scenario:
    """The scenario of a parsed TOML document; an invalid entry raises :class:`ScenarioError` naming
    its key (e.g. ``[channel] sigma_d_m``, ``stations[2].pos_m``, ``faults[1].offset_m``).
    ``base_dir``: where ``[site] stations_geojson`` is looked up (the scenario file's folder)."""
    validate(raw)
    raw, site = _place_on_site(raw, None if base_dir is None else Path(base_dir))
    seed = int(raw.get("seed", 0))
    frame = raw.get("frame", {})
    z_ref = int(frame.get("z_ref", 4))
    ids, phys, join_ids, where = (_explicit_stations(raw) if "stations" in raw else _random_stations(raw, seed))
    _check_ids(raw, ids, join_ids, where)
    order = np.argsort(ids)
    where_by_id = {ids[k]: where[k] for k in range(len(ids))}
    ids = [ids[i] for i in order]
    phys = phys[order]
    _check_geometry(ids, phys, where_by_id)
    if "z_ref" in frame and z_ref not in ids and len(ids) > 3:
        raise ScenarioError(f"[frame] z_ref: no station {z_ref} (expected one of the station ids "
                            f"{ids[0]}..{ids[-1]}; it fixes the sign of +Z)")
    zi = ids.index(z_ref) if z_ref in ids else 3
    pos, R, t = to_network_frame(phys, z_ref=zi)
    init = raw.get("init", {})
    if float(init.get("sigma0_m", 10.0)) == 0.0 and len(ids) > 3 and pos[2, 1] < 0.0:
        # without a coarse fix the stations take the founders to turn counterclockwise, seen from the
        # side of station z_ref (ranges alone cannot tell a field from its mirror image)
        raise ScenarioError(f"[init] sigma0_m: 0 (no coarse fix) needs station 3 on the left of the line from "
                            f"station 1 to station 2, seen from above (from station {z_ref}'s side of their "
                            "plane); here it is on the right (expected swapped ids 1 and 2, or sigma0_m > 0)")
    survey = raw.get("survey", {})
    channel = ChannelParams(**raw.get("channel", {}))
    _check_poll_slot(Tdma(**raw.get("tdma", {})), channel, pos)
    if "radio" in raw:  # links and their timing noise from the radio (net/radio.py)
        radio = parse_radio(raw["radio"], ScenarioError, base_dir=base_dir)  # [radio] terrain beside the file
        channel = replace(channel, radio=radio.in_frame(R, t))
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
        datum=str(survey.get("datum", "founders")),
        join_ids=join_ids,
        aircraft=dict(raw.get("aircraft", {})),
        raw=raw,
        clock=_clock(raw, channel),
        links=parse_links(raw.get("links", []), ids),
        faults=parse_faults(raw.get("faults", []), ids),
        site=None if site is None else site.with_network(R, t),
    )


# ---------------------------------------------------------------- per-link channel and station faults
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
    "leave": {"at_s": "float"},
    "kill": {"at_s": "float"},
}
FAULT_OPTIONAL = {"from_s": 0.0, "at_s": 0.0}
DEPARTURE_KINDS = ("leave", "kill")  # the station falls silent at at_s (required)


@dataclass(frozen=True)
class StationFault:
    """``[[faults]]`` entry; applied in the station's shell (simulator and node alike), never in its
    estimator. ``liar``: broadcasts (nav, range answers) carry ``pos_m + offset_m`` from ``from_s``;
    ``range_bias``: every range of ``station`` is ``bias_m`` long from ``from_s``; ``clock_jump``: its
    clock steps by ``jump_s`` at true time ``at_s``; ``bad_fix``: its coarse fix is off by ``offset_m``
    while it claims ``sigma0_m`` (default: the scenario's); ``leave`` / ``kill``: the station falls
    silent at true time ``at_s`` (a departure or a SIGKILL; in the simulator both stop the station)."""

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
        if self.kind in ("clock_jump", *DEPARTURE_KINDS):
            return self.at_s
        return 0.0 if self.kind == "bad_fix" else self.from_s


def _num(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise ScenarioError(f"{where}: got {v!r} (expected a finite number)")
    return float(v)


def _station(v: Any, where: str, ids: list[int]) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise ScenarioError(f"{where}: got {v!r} (expected a station id, an integer)")
    if v not in ids:
        raise ScenarioError(f"{where}: no station {v} in this scenario (expected one of ids {ids[0]}..{ids[-1]})")
    return v


def parse_faults(entries: Any, ids: list[int]) -> list[StationFault]:
    if not isinstance(entries, list):
        raise ScenarioError(f"faults: got {entries!r} (expected an array of tables, [[faults]])")
    out = []
    for i, e in enumerate(entries):
        w = f"faults[{i}]"
        if not isinstance(e, dict):
            raise ScenarioError(f"{w}: got {e!r} (expected a table)")
        kind = e.get("kind")
        if kind not in FAULT_KEYS:
            raise ScenarioError(f"{w}.kind: got {kind!r} (expected one of {', '.join(sorted(FAULT_KEYS))})")
        if "station" not in e:
            raise ScenarioError(f"{w}.station: missing (expected the faulty station's id)")
        spec = FAULT_KEYS[kind]
        unknown = set(e) - set(spec) - {"kind", "station"}
        if unknown:
            raise ScenarioError(f"{w}.{sorted(unknown)[0]}: unknown key for kind {kind!r} "
                                f"(expected kind, station, {', '.join(spec)})")
        kw: dict[str, Any] = {"kind": kind, "station": _station(e["station"], f"{w}.station", ids)}
        for key, typ in spec.items():
            if key not in e:
                if (key in FAULT_OPTIONAL and kind not in DEPARTURE_KINDS) or (kind == "bad_fix" and key == "sigma0_m"):
                    continue
                raise ScenarioError(f"{w}.{key}: missing (expected it: required for kind {kind!r})")
            v = e[key]
            if typ == "vec3":
                if not isinstance(v, list) or len(v) != 3:
                    raise ScenarioError(f"{w}.{key}: got {v!r} (expected 3 numbers [x, y, z] in metres)")
                kw[key] = tuple(_num(x, f"{w}.{key}") for x in v)
            else:
                kw[key] = _num(v, f"{w}.{key}")
        if kw.get("sigma0_m", 1.0) is not None and kw.get("sigma0_m", 1.0) < 0:
            raise ScenarioError(f"{w}.sigma0_m: got {kw['sigma0_m']!r} (expected a number >= 0)")
        out.append(StationFault(**kw))
    return out


def parse_links(entries: Any, ids: list[int]) -> list[LinkOverride]:
    if not isinstance(entries, list):
        raise ScenarioError(f"links: got {entries!r} (expected an array of tables, [[links]])")
    out = []
    for i, e in enumerate(entries):
        w = f"links[{i}]"
        if not isinstance(e, dict):
            raise ScenarioError(f"{w}: got {e!r} (expected a table)")
        unknown = set(e) - {"station", "stations", "nlos_prob", "nlos_bias_m", "loss_prob", "bias_m"}
        if unknown:
            raise ScenarioError(f"{w}.{sorted(unknown)[0]}: unknown key (expected station or stations, "
                                "nlos_prob, nlos_bias_m, loss_prob, bias_m)")
        if ("station" in e) == ("stations" in e):
            raise ScenarioError(f"{w}.station: both or neither of station and stations (expected exactly one of "
                                "station = id or stations = [a, b])")
        if "station" in e:
            sel = (_station(e["station"], f"{w}.station", ids),)
        else:
            v = e["stations"]
            if not isinstance(v, list) or len(v) != 2 or v[0] == v[1]:
                raise ScenarioError(f"{w}.stations: got {v!r} (expected two different station ids [a, b])")
            sel = tuple(_station(x, f"{w}.stations", ids) for x in v)
        kw: dict[str, Any] = {}
        for key in ("nlos_prob", "loss_prob"):
            if key in e:
                kw[key] = _num(e[key], f"{w}.{key}")
                if not 0.0 <= kw[key] <= 1.0:
                    raise ScenarioError(f"{w}.{key}: got {kw[key]!r} (expected a probability in [0, 1])")
        for key in ("nlos_bias_m", "bias_m"):
            if key in e:
                kw[key] = _num(e[key], f"{w}.{key}")
        if kw.get("nlos_bias_m", 0.0) < 0:
            raise ScenarioError(f"{w}.nlos_bias_m: got {kw['nlos_bias_m']!r} (expected a number >= 0)")
        out.append(LinkOverride(sel, **kw))
    return out


# ---------------------------------------------------------------- validation of the other sections
def _clock(raw: dict, channel: ChannelParams) -> ClockParams:
    try:
        return clock_params(raw.get("clock"), channel.clock_offset_s, channel.clock_drift_ppm)
    except ValueError as e:  # net/clock.py names the key ("[clock] model: ...")
        raise ScenarioError(str(e)) from None


_NONNEG, _PROB, _POS = "a number >= 0", "a probability in [0, 1]", "a number > 0"
_SECTION_RULES: dict[str, tuple[type, dict[str, str]]] = {
    "tdma": (Tdma, {"cycle_s": _POS, "slot_s": _POS, "reply_spacing_s": _POS, "frame_s": _NONNEG,
                    "guard_s": _NONNEG}),  # assignment, cycle_slots, ranging: _validate_tdma
    "channel": (ChannelParams, {"sigma_d_m": _NONNEG, "nlos_prob": _PROB, "nlos_bias_m": _NONNEG,
                                "loss_prob": _PROB, "clock_offset_s": _NONNEG, "clock_drift_ppm": _NONNEG,
                                "turnaround_s": _NONNEG}),
    "net": (NetFaults, {"delay_s": _NONNEG, "jitter_s": _NONNEG, "loss_prob": _PROB, "dup_prob": _PROB}),
    "init": (None, {"sigma0_m": _NONNEG}),
}
_LAYOUT_KEYS = ("kind", "n", "area_m", "min_separation_m", "join_ids", "joiners", "founders_within_m")
_SURVEY_KEYS = ("estimator", "ranges_per_update", "datum")
DATUMS = ("founders", "field")

TOP_LEVEL_KEYS = ("name", "description", "seed")
# sections: tables, and arrays of tables ([[stations]], [[links]], [[faults]])
SECTIONS = ("frame", "site", "layout", "stations", "tdma", "channel", "radio", "clock", "net", "init", "survey", "aircraft",
            "vehicle", "links", "faults")
# the names stations/estimators.py (ESTIMATORS) and aircraft/ (models.ALGOS, ins-ekf, triad) accept; net
# may not import them, tests/net/test_scenario_errors.py keeps the lists equal
SURVEY_ESTIMATORS = ("dmap", "dmap-nlos", "dmap-ls", "seed-ukf")
AIRCRAFT_ALGOS = ("lsq-pr", "lsq-tdoa", "ekf-pr", "ekf-tdoa", "ukf-pr", "ukf-tdoa", "ins-ekf", "triad")


def _did_you_mean(name: str, choices: Any) -> str:
    close = difflib.get_close_matches(name, list(choices), n=1)
    return f"; did you mean {close[0]}?" if close else ""


def _table(raw: dict, key: str) -> dict:
    v = raw.get(key, {})
    if not isinstance(v, dict):
        raise ScenarioError(f"[{key}]: got {v!r} (expected a table)")
    return v


def _int(v: Any, where: str, low: int) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < low:
        raise ScenarioError(f"{where}: got {v!r} (expected an integer >= {low})")
    return v


def _known(tab: dict, where: str, keys: Any) -> None:
    unknown = sorted(set(tab) - set(keys))
    if unknown:
        raise ScenarioError(f"{where} {unknown[0]}: unknown key (expected one of {', '.join(sorted(keys))}"
                            f"{_did_you_mean(unknown[0], keys)})")


def _check_rule(v: float, where: str, rule: str) -> None:
    ok = {_NONNEG: v >= 0.0, _PROB: 0.0 <= v <= 1.0, _POS: v > 0.0}[rule]
    if not ok:
        raise ScenarioError(f"{where}: got {v!r} (expected {rule})")


def _validate_top_level(raw: dict) -> None:
    """Only known top-level keys and sections: a typo (``sead = 3``, ``[layot]``) is an error, not a default."""
    for k, v in raw.items():
        if k in TOP_LEVEL_KEYS or k in SECTIONS:
            continue
        if isinstance(v, dict) or (isinstance(v, list) and v and all(isinstance(e, dict) for e in v)):
            names = [f"[{s}]" for s in SECTIONS]
            raise ScenarioError(f"[{k}]: unknown section (expected one of {', '.join(names)}"
                                f"{_did_you_mean(f'[{k}]', names)})")
        raise ScenarioError(f"{k}: unknown top-level key (expected {', '.join(TOP_LEVEL_KEYS)} or a section"
                            f"{_did_you_mean(k, TOP_LEVEL_KEYS + SECTIONS)})")
    for k in ("name", "description"):
        if k in raw and not isinstance(raw[k], str):
            raise ScenarioError(f"{k}: got {raw[k]!r} (expected a string)")
    if "seed" in raw:
        _int(raw["seed"], "seed", 0)


def _validate_params(raw: dict) -> None:
    for key, (cls, rules) in _SECTION_RULES.items():
        tab = _table(raw, key)
        _known(tab, f"[{key}]", [f.name for f in fields(cls) if f.name != "radio"] if cls is not None else rules)
        for k, v in tab.items():
            if k in rules:
                _check_rule(_num(v, f"[{key}] {k}"), f"[{key}] {k}", rules[k])
    _validate_tdma(_table(raw, "tdma"))


ASSIGNMENTS = ("fixed", "distributed")
RANGINGS = ("addressed", "poll")  # [tdma] ranging: the addressed exchange (v1) or one poll per slot (v2)
MAX_CYCLE_SLOTS = 1024  # net.messages.MAX_SLOTS: a nav's slot summary has one entry per slot at most


def _validate_tdma(tdma: dict) -> None:
    slot_s, cycle_s = _num(tdma.get("slot_s", 0.01), "[tdma] slot_s"), _num(tdma.get("cycle_s", 1.0), "[tdma] cycle_s")
    if slot_s > cycle_s:
        raise ScenarioError(f"[tdma] slot_s: {slot_s:g} s is longer than cycle_s {cycle_s:g} s "
                            "(expected slot_s <= cycle_s)")
    how = tdma.get("assignment", "fixed")
    if how not in ASSIGNMENTS:
        raise ScenarioError(f"[tdma] assignment: got {how!r} (expected one of {', '.join(ASSIGNMENTS)}"
                            f"{_did_you_mean(str(how), ASSIGNMENTS)})")
    n = _int(tdma.get("cycle_slots", 0), "[tdma] cycle_slots", 0)
    slots = int(round(cycle_s / slot_s))
    if how == "distributed" and n == 0 and slots > MAX_CYCLE_SLOTS:
        raise ScenarioError(f"[tdma] cycle_slots: 0 (all {slots} slots of the cycle) (expected at most "
                            f"{MAX_CYCLE_SLOTS} slots for the distributed assignment: set cycle_slots)")
    if n > min(slots, MAX_CYCLE_SLOTS):
        raise ScenarioError(f"[tdma] cycle_slots: got {n} (expected at most the cycle's {slots} slots "
                            f"(cycle_s {cycle_s:g} / slot_s {slot_s:g}) and at most {MAX_CYCLE_SLOTS}; 0: all)")
    if how != "distributed" and n:
        raise ScenarioError(f"[tdma] cycle_slots: {n} with assignment {how!r} (expected it only with "
                            "assignment = \"distributed\"; the fixed plan gives station id slot id - 1)")
    ranging = tdma.get("ranging", "addressed")
    if ranging not in RANGINGS:
        raise ScenarioError(f"[tdma] ranging: got {ranging!r} (expected one of {', '.join(RANGINGS)}"
                            f"{_did_you_mean(str(ranging), RANGINGS)})")
    if ranging == "poll" and how == "distributed":
        raise ScenarioError("[tdma] ranging: \"poll\" with assignment \"distributed\" (expected assignment "
                            "\"fixed\" with the poll: protocol v2's first phase runs on the fixed plan)")


def _check_poll_slot(tdma: Tdma, channel: ChannelParams, pos_m: np.ndarray) -> None:
    """``[tdma] ranging = "poll"``: the poll, one reply per other station and the final fit in one slot
    (rule V8, ``net.slotplan.check_slot_plan``) at the field's diameter (the longest path between two
    stations that may hear each other); refused with the keys named."""
    if not tdma.poll:
        return
    p = np.asarray(pos_m, float)
    diameter_m = float(np.max(np.linalg.norm(p[:, None, :] - p[None, :, :], axis=-1))) if len(p) else 0.0
    try:
        check_slot_plan(tdma.slot_s, len(p) - 1, channel.turnaround_s, tdma.reply_spacing_s, diameter_m,
                        tdma.frame_s, tdma.guard_s)
    except ValueError as e:
        raise ScenarioError(f"{e} ([tdma] ranging = \"poll\", {len(p)} stations, field diameter "
                            f"{diameter_m:.0f} m)") from None


def _validate_layout(raw: dict) -> None:
    lay = _table(raw, "layout")
    _known(lay, "[layout]", _LAYOUT_KEYS)
    if lay.get("kind", "random") != "random":
        raise ScenarioError(f"[layout] kind: got {lay['kind']!r} (expected \"random\"; explicit positions "
                            "go in [[stations]])")
    if "n" in lay:
        _int(lay["n"], "[layout] n", 3)
    if "joiners" in lay:
        _int(lay["joiners"], "[layout] joiners", 0)
    if "founders_within_m" in lay:
        _check_rule(_num(lay["founders_within_m"], "[layout] founders_within_m"), "[layout] founders_within_m", _POS)
    if "min_separation_m" in lay:
        _check_rule(_num(lay["min_separation_m"], "[layout] min_separation_m"), "[layout] min_separation_m", _NONNEG)
    area = lay.get("area_m", (1.0, 1.0, 1.0))
    if not isinstance(area, (list, tuple)) or len(area) != 3:
        raise ScenarioError(f"[layout] area_m: got {area!r} (expected 3 numbers [x, y, z] in metres)")
    for i, v in enumerate(area):
        _check_rule(_num(v, f"[layout] area_m[{i}]"), f"[layout] area_m[{i}]", _NONNEG)
    join = lay.get("join_ids", [])
    if not isinstance(join, list):
        raise ScenarioError(f"[layout] join_ids: got {join!r} (expected a list of station ids)")
    for i, v in enumerate(join):
        _int(v, f"[layout] join_ids[{i}]", 1)


def _validate_stations(raw: dict) -> None:
    st = raw.get("stations")
    if st is None:
        return
    if not isinstance(st, list) or not st:
        raise ScenarioError(f"stations: got {st!r} (expected a non-empty array of tables, [[stations]])")
    for i, e in enumerate(st):
        w = f"stations[{i}]"
        if not isinstance(e, dict):
            raise ScenarioError(f"{w}: got {e!r} (expected a table)")
        keys = ("id", "pos_m", "join") + _GEO_KEYS
        unknown = sorted(set(e) - set(keys))
        if unknown:
            raise ScenarioError(f"{w}.{unknown[0]}: unknown key (expected id, pos_m or lat_deg/lon_deg/h_m, join"
                                f"{_did_you_mean(unknown[0], keys)})")
        if "id" not in e:
            raise ScenarioError(f"{w}.id: missing (expected the station id, an integer >= 1)")
        _int(e["id"], f"{w}.id", 1)
        if not isinstance(e.get("join", False), bool):
            raise ScenarioError(f"{w}.join: got {e['join']!r} (expected true or false)")
        if any(k in e for k in _GEO_KEYS):
            if "pos_m" in e:
                raise ScenarioError(f"{w}.pos_m: both pos_m and lat_deg/lon_deg/h_m (expected one of them)")
            _geodetic(e, w)
            continue
        pos = e.get("pos_m")
        if pos is None:
            raise ScenarioError(f"{w}.pos_m: missing (expected physical coordinates [x, y, z], m, or lat_deg, "
                                "lon_deg, h_m)")
        if not isinstance(pos, list) or len(pos) != 3:
            raise ScenarioError(f"{w}.pos_m: got {pos!r} (expected 3 numbers [x, y, z] in metres)")
        for j, v in enumerate(pos):
            _num(v, f"{w}.pos_m[{j}]")


def _validate_clock(raw: dict) -> None:
    """``[clock]``: a known model and numbers >= 0 (``net/clock.py`` builds the parameters)."""
    clock = _table(raw, "clock")
    models = sorted(PRESETS) + ["custom"]
    model = clock.get("model", "tcxo")
    if model not in models:
        raise ScenarioError(f"[clock] model: unknown model {model!r} (expected one of {', '.join(models)}"
                            f"{_did_you_mean(str(model), models)})")
    _known(clock, "[clock]", ["model", *(f.name for f in fields(ClockParams) if f.name != "model")])
    for k, v in clock.items():
        if k != "model":
            _check_rule(_num(v, f"[clock] {k}"), f"[clock] {k}", _NONNEG)


def _validate_survey(raw: dict) -> None:
    survey = _table(raw, "survey")
    _known(survey, "[survey]", _SURVEY_KEYS)
    name = survey.get("estimator", "dmap")
    if name not in SURVEY_ESTIMATORS:
        raise ScenarioError(f"[survey] estimator: unknown estimator {name!r} (expected one of "
                            f"{', '.join(SURVEY_ESTIMATORS)}{_did_you_mean(str(name), SURVEY_ESTIMATORS)})")
    if name == "seed-ukf" and _table(raw, "init").get("sigma0_m", 10.0) == 0:
        raise ScenarioError("[survey] estimator: seed-ukf starts from the coarse fix, but [init] sigma0_m = 0 "
                            "(no fix) (expected sigma0_m > 0, or estimator dmap)")
    if "ranges_per_update" in survey:
        _int(survey["ranges_per_update"], "[survey] ranges_per_update", 1)
    if survey.get("datum", "founders") not in DATUMS:
        raise ScenarioError(f"[survey] datum: {survey['datum']!r} (expected one of {', '.join(DATUMS)})")


def _validate_aircraft(raw: dict) -> None:
    """The parts of ``[aircraft]`` a launch needs first (the rest: ``aircraft/config.py``)."""
    ac = _table(raw, "aircraft")
    _table(raw, "vehicle")
    if "algos" not in ac:
        return
    algos = ac["algos"]
    if not isinstance(algos, list) or not algos:
        raise ScenarioError(f"[aircraft] algos: got {algos!r} (expected a list of algorithm names, e.g. "
                            "[\"ekf-pr\"])")
    for a in algos:
        if a not in AIRCRAFT_ALGOS:
            raise ScenarioError(f"[aircraft] algos: unknown algorithm {a!r} (expected one of "
                                f"{', '.join(AIRCRAFT_ALGOS)}{_did_you_mean(str(a), AIRCRAFT_ALGOS)})")


def validate(raw: dict[str, Any]) -> None:
    """Check the sections :func:`from_dict` reads (``[[faults]]`` and ``[[links]]`` are checked by their
    parsers, the stations' ids and geometry once they are placed); raises :class:`ScenarioError`
    naming the first bad key."""
    if not isinstance(raw, dict):
        raise ScenarioError(f"scenario: got a {type(raw).__name__} (expected a table)")
    _validate_top_level(raw)
    _validate_params(raw)
    _validate_layout(raw)
    _validate_stations(raw)
    _validate_site(raw)
    if "radio" in raw:
        parse_radio(raw["radio"], ScenarioError, load_terrain=False)  # the terrain file: from_dict
    frame = _table(raw, "frame")
    _known(frame, "[frame]", ("z_ref",))
    if "z_ref" in frame:
        _int(frame["z_ref"], "[frame] z_ref", 1)
    _validate_clock(raw)
    _validate_survey(raw)
    _validate_aircraft(raw)


class WorldPositions(dict):
    """Station id -> true position, as the receive side's channel looks senders up: a sender the
    scenario does not list is a hot-joiner from outside it, at :func:`joiner_position` - the same
    place its own process puts itself (drawn from the scenario, so every process agrees)."""

    def __init__(self, known: dict, scn: Scenario):
        super().__init__(known)
        self.scn = scn

    def get(self, station_id, default=None):
        if station_id not in self and isinstance(station_id, int) and 1 <= station_id <= 65535:
            self[station_id] = joiner_position(self.scn, station_id)
        return super().get(station_id, default)


def joiner_position(scn: Scenario, station_id: int) -> np.ndarray:
    """True position (network frame) of a hot-joining station ``station_id`` that ``scn`` does not list,
    drawn from the scenario alone. Random layout: the scenario's own joiner stream (``[layout]
    joiners``) extended to this id - station 11 of seed000 sits where seed000-join puts it. Listed
    stations: uniform in the box the listed stations span, at least 100 m (horizontally) from each,
    from the stream (seed, 7, id)."""
    if station_id in scn.ids:
        return np.asarray(scn.true_pos(station_id), float)
    lay = scn.raw.get("layout")
    if "stations" not in scn.raw and isinstance(lay, dict):
        n = int(lay.get("n", 10))
        if station_id > n:
            raw = {k: (dict(v) if isinstance(v, dict) else v) for k, v in scn.raw.items()}
            raw["layout"] = {**lay, "n": n, "joiners": station_id - n}
            return np.asarray(from_dict(raw).true_pos(station_id), float)
    pos = np.asarray(scn.pos_m, float)
    lo, hi = pos.min(axis=0), pos.max(axis=0)
    rng = np.random.default_rng([int(scn.seed), 7, int(station_id)])
    p = lo + rng.uniform(0.0, 1.0, 3) * (hi - lo)
    for _ in range(1000):
        if all(np.hypot(*(p[:2] - q[:2])) >= 100.0 for q in pos):
            break
        p = lo + rng.uniform(0.0, 1.0, 3) * (hi - lo)
    return p
