"""Foxglove view of a LARNS recording: JSON channels next to the msgpack wire channels.

Foxglove (and other MCAP viewers) cannot decode our msgpack envelopes, so the recorder also writes
(on by default, ``larns record --no-foxglove`` to skip) - and ``larns export run.mcap -o out.mcap``
adds to an old log - JSON channels (``message_encoding`` "json", schema encoding "jsonschema", no
NaN or infinity anywhere):

| topic | schema | what |
|---|---|---|
| ``larns/foxglove/tf`` | ``foxglove.FrameTransform`` | frame ``network`` -> ``station_<id>`` (estimate), ``station_<id>_truth``, ``<aircraft>_<algo>``, ``<aircraft>_truth`` (and ``<vehicle>_...``) |
| ``larns/foxglove/scene`` | ``foxglove.SceneUpdate`` | 3D: station / aircraft estimates as 3-sigma covariance ellipsoids, truth as small cubes, labels |
| ``larns/foxglove/station/<id>`` | ``larns.StationEstimate`` | plottable numbers: position, sigmas, 3-sigma bound, error vs truth, updates |
| ``larns/foxglove/aircraft/<name>/<algo>`` | ``larns.AircraftEstimate`` | same for each aircraft algorithm |
| ``larns/foxglove/vehicle/<name>/<algo>`` | ``larns.AircraftEstimate`` | same for a ground vehicle (``larns vehicle``) |
| ``larns/foxglove/fix/station/<id>``, ``.../fix/aircraft/<name>/<algo>``, ``.../fix/vehicle/<name>/<algo>`` | ``foxglove.LocationFix`` | with a site (scenario ``[site]``): each estimate on WGS84, its covariance in ENU (``position_covariance_type`` 3, known), for the Map panel; ``frame_id`` the estimate's frame of the transforms above |
| ``larns/foxglove/fix/station/<id>/truth``, ``.../fix/<role>/<name>/truth`` | ``foxglove.LocationFix`` | the truth on WGS84 (zero covariance, type 0) |

The ``foxglove.*`` JSON Schemas are generated from the Foxglove SDK's typed schemas
(:mod:`larns.viz.sdk_schema`), the same messages the live view (``larns view``) sends: one
definition of what a viewer sees, live or recorded.

Open a recording in Foxglove and load ``docs/foxglove-layout.json`` (3D panel + error plots).
The conversion is a pure function of the wire messages (:class:`FoxgloveView`), shared by the
recorder and ``larns export``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from .sdk_schema import json_schema

FRAME = "network"
TF_TOPIC = "larns/foxglove/tf"
SCENE_TOPIC = "larns/foxglove/scene"
N_SIGMA = 3.0
MIN_DIAMETER_M = 0.5  # frame stations have zero covariance: keep them visible

# --------------------------------------------------------------------------- JSON Schemas (draft 7)
# The Foxglove messages: generated from the Foxglove SDK's own schemas (larns/viz/sdk_schema.py), the
# same definitions the live view sends as typed messages (larns/viz/live.py). The larns.* ones are ours.
_NUM = {"type": "number"}

SCHEMAS: dict[str, dict] = {name: json_schema(name) for name in ("foxglove.FrameTransform", "foxglove.SceneUpdate",
                                                                  "foxglove.LocationFix")}
_EST_PROPS = {"t_s": _NUM, "x_m": _NUM, "y_m": _NUM, "z_m": _NUM, "sigma_x_m": _NUM, "sigma_y_m": _NUM,
              "sigma_z_m": _NUM, "sigma_m": _NUM, "bound3_m": _NUM, "n_updates": {"type": "integer"},
              "err_m": _NUM, "err_x_m": _NUM, "err_y_m": _NUM, "err_z_m": _NUM,
              "err_over_sigma": _NUM}
SCHEMAS["larns.StationEstimate"] = {
    "title": "larns.StationEstimate",
    "description": "A station's self-survey estimate as plottable numbers (network frame, metres); error "
                   "fields only when the truth topic was recorded. bound3_m = 3 * sqrt(trace P).",
    "type": "object", "additionalProperties": False,
    "properties": {**_EST_PROPS, "id": {"type": "integer"}, "state": {"type": "string"},
                   "estimator": {"type": "string"}},
    "required": ["t_s", "id", "x_m", "y_m", "z_m", "sigma_m", "bound3_m", "n_updates", "state"]}
SCHEMAS["larns.AircraftEstimate"] = {
    "title": "larns.AircraftEstimate",
    "description": "An aircraft position estimate of one algorithm as plottable numbers; error fields "
                   "only when the aircraft truth topic was recorded.",
    "type": "object", "additionalProperties": False,
    "properties": {**_EST_PROPS, "name": {"type": "string"}, "algo": {"type": "string"}},
    "required": ["t_s", "name", "algo", "x_m", "y_m", "z_m", "sigma_m", "bound3_m"]}

SCHEMA_BYTES = {k: json.dumps(v, sort_keys=True).encode() for k, v in SCHEMAS.items()}

COLORS = {"station": (0.15, 0.45, 0.95, 0.45), "frame": (0.95, 0.2, 0.2, 0.6), "truth": (0.1, 0.8, 0.2, 0.9),
          "aircraft": (1.0, 0.6, 0.0, 0.45), "ac_truth": (0.1, 0.8, 0.2, 0.9)}
FIX_KNOWN, FIX_UNKNOWN = 3, 0  # foxglove.LocationFix position_covariance_type: KNOWN, UNKNOWN


def fix_topic(role: str, name, leaf: str | None = None) -> str:
    """The ``foxglove.LocationFix`` topic of a station (``role`` "station", ``name`` its id), an
    aircraft or a vehicle (``leaf`` its algorithm), or of their truth (``leaf`` "truth")."""
    return "/".join(["larns/foxglove/fix", role, str(name)] + ([leaf] if leaf else []))


def location_fix(site, ns: int, frame_id: str, pos_n, cov_n=None, color=COLORS["station"]) -> dict[str, Any]:
    """A ``foxglove.LocationFix`` (JSON layout) of a network-frame position (3,) and covariance (3, 3)
    on the ``site`` (:class:`nav.site.Site`): latitude / longitude / ellipsoidal height and the
    covariance in the ENU tangent plane at the point, row-major (type 3, known); no covariance:
    zeros, type 0 (unknown)."""
    lat, lon, h = site.net_to_geodetic(np.asarray(pos_n, float))
    cov = [0.0] * 9
    kind = FIX_UNKNOWN
    if cov_n is not None:
        C = np.asarray(cov_n, float)
        if np.all(np.isfinite(C)):
            cov = [_f(v) for v in site.net_cov_to_enu(C, lat, lon).ravel()]
            kind = FIX_KNOWN
    return {"timestamp": stamp(ns), "frame_id": frame_id, "latitude": _f(lat), "longitude": _f(lon),
            "altitude": _f(h), "position_covariance": cov, "position_covariance_type": kind, "heading": 0.0,
            "velocity": {"x": 0.0, "y": 0.0, "z": 0.0}, "color": _color(color), "metadata": []}


# --------------------------------------------------------------------------- helpers

def stamp(ns: int) -> dict[str, int]:
    ns = max(int(ns), 0)
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _f(x: float) -> float:
    x = float(x)
    return x if math.isfinite(x) else 0.0


def _vec(p) -> dict[str, float]:
    return {"x": _f(p[0]), "y": _f(p[1]), "z": _f(p[2])}


def _color(c) -> dict[str, float]:
    return {"r": c[0], "g": c[1], "b": c[2], "a": c[3]}


IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def quat_from_matrix(R: np.ndarray) -> dict[str, float]:
    """Unit quaternion of a proper rotation matrix (3, 3) (Shepperd's method)."""
    R = np.asarray(R, float)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + R[0, 0] - R[1, 1] - R[2, 2], 1e-300))
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(max(1.0 + R[1, 1] - R[0, 0] - R[2, 2], 1e-300))
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = 2.0 * math.sqrt(max(1.0 + R[2, 2] - R[0, 0] - R[1, 1], 1e-300))
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    n = math.sqrt(w * w + x * x + y * y + z * z) or 1.0
    return {"x": _f(x / n), "y": _f(y / n), "z": _f(z / n), "w": _f(w / n)}


def ellipsoid(cov_m2, n_sigma: float = N_SIGMA) -> tuple[dict, dict]:
    """(size, orientation) of the ``n_sigma`` covariance ellipsoid: diameters along the principal
    axes ``2 n sqrt(lambda_i)`` and the rotation of the eigenvector basis (det +1)."""
    C = np.asarray(cov_m2, float)
    C = 0.5 * (C + C.T)
    if not np.all(np.isfinite(C)):
        return _vec([MIN_DIAMETER_M] * 3), dict(IDENTITY)
    w, V = np.linalg.eigh(C)
    if np.linalg.det(V) < 0:
        V[:, 0] = -V[:, 0]
    d = np.maximum(2.0 * n_sigma * np.sqrt(np.maximum(w, 0.0)), MIN_DIAMETER_M)
    return _vec(d), quat_from_matrix(V)


def _empty_entity(ns: int, eid: str) -> dict[str, Any]:
    return {"timestamp": stamp(ns), "frame_id": FRAME, "id": eid, "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False, "metadata": [], "arrows": [], "cubes": [], "spheres": [], "cylinders": [],
            "lines": [], "triangles": [], "texts": [], "models": []}


def _label(pos, text: str, color) -> dict[str, Any]:
    return {"pose": {"position": _vec(np.asarray(pos, float) + [0.0, 0.0, 5.0]), "orientation": dict(IDENTITY)},
            "billboard": True, "font_size": 14.0, "scale_invariant": True, "color": _color(color), "text": text}


def _tf(ns: int, child: str, pos) -> dict[str, Any]:
    return {"timestamp": stamp(ns), "parent_frame_id": FRAME, "child_frame_id": child, "translation": _vec(pos),
            "rotation": dict(IDENTITY)}


def _numbers(pos, cov, truth) -> dict[str, float]:
    pos = np.asarray(pos, float)
    C = np.asarray(cov, float)
    from ..log.series import sigma_m

    var = np.maximum(np.diag(C), 0.0)
    sig = float(sigma_m(C))
    out = {"x_m": _f(pos[0]), "y_m": _f(pos[1]), "z_m": _f(pos[2]),
           "sigma_x_m": _f(math.sqrt(var[0])), "sigma_y_m": _f(math.sqrt(var[1])),
           "sigma_z_m": _f(math.sqrt(var[2])), "sigma_m": _f(sig), "bound3_m": _f(N_SIGMA * sig)}
    if truth is not None:
        e = pos - np.asarray(truth, float)
        if np.all(np.isfinite(e)):
            out.update(err_m=_f(np.linalg.norm(e)), err_x_m=_f(e[0]), err_y_m=_f(e[1]), err_z_m=_f(e[2]))
            if out["sigma_m"] > 0:
                out["err_over_sigma"] = _f(out["err_m"] / out["sigma_m"])
    return out


# --------------------------------------------------------------------------- the converter

class FoxgloveView:
    """Stateful converter: ``convert(key, msg, log_ns)`` -> [(topic, schema name, JSON dict)].

    Keeps the latest truth per station / aircraft to compute errors. Pure (no I/O). With a ``site``
    (:class:`nav.site.Site`, the scenario's ``[site]``) every estimate and truth is also a
    ``foxglove.LocationFix`` on WGS84."""

    def __init__(self, site=None) -> None:
        self.site = site
        self.truth: dict[int, list[float]] = {}
        self.ac_truth: dict[tuple[str, str], tuple[float, list[float]]] = {}  # (role, name) -> (t_s, pos)
        self.count = 0

    def convert(self, msg: dict, log_ns: int) -> list[tuple[str, str, dict]]:
        kind = msg.get("kind")
        out: list[tuple[str, str, dict]] = []
        if kind == "truth":
            sid = msg["src"]
            first = sid not in self.truth
            self.truth[sid] = msg["pos_m"]
            if first:  # truth is static for stations: one transform and one cube
                ent = _empty_entity(log_ns, f"station/{sid}/truth")
                ent["cubes"].append({"pose": {"position": _vec(msg["pos_m"]), "orientation": dict(IDENTITY)},
                                     "size": _vec([2.0, 2.0, 2.0]), "color": _color(COLORS["truth"])})
                out.append((TF_TOPIC, "foxglove.FrameTransform", _tf(log_ns, f"station_{sid}_truth", msg["pos_m"])))
                out.append((SCENE_TOPIC, "foxglove.SceneUpdate", {"deletions": [], "entities": [ent]}))
                if self.site is not None:
                    out.append((fix_topic("station", sid, "truth"), "foxglove.LocationFix",
                                location_fix(self.site, log_ns, f"station_{sid}_truth", msg["pos_m"],
                                             color=COLORS["truth"])))
        elif kind == "estimate":
            sid = msg["src"]
            size, q = ellipsoid(msg["cov_m2"])
            ent = _empty_entity(log_ns, f"station/{sid}")
            col = COLORS["frame" if msg["state"] == "frame" else "station"]
            ent["spheres"].append({"pose": {"position": _vec(msg["pos_m"]), "orientation": q}, "size": size,
                                   "color": _color(col)})
            ent["texts"].append(_label(msg["pos_m"], f"S{sid}", col[:3] + (1.0,)))
            ent["metadata"] = [{"key": "state", "value": msg["state"]},
                               {"key": "n_updates", "value": str(msg["n_updates"])}]
            nums = _numbers(msg["pos_m"], msg["cov_m2"], self.truth.get(sid))
            rec = {"t_s": _f(msg["t_s"]), "id": int(sid), "n_updates": int(msg["n_updates"]),
                   "state": msg["state"], "estimator": str(msg.get("estimator", "")), **nums}
            out.append((TF_TOPIC, "foxglove.FrameTransform", _tf(log_ns, f"station_{sid}", msg["pos_m"])))
            out.append((SCENE_TOPIC, "foxglove.SceneUpdate", {"deletions": [], "entities": [ent]}))
            out.append((f"larns/foxglove/station/{sid}", "larns.StationEstimate", rec))
            if self.site is not None:
                out.append((fix_topic("station", sid), "foxglove.LocationFix",
                            location_fix(self.site, log_ns, f"station_{sid}", msg["pos_m"], msg["cov_m2"], col)))
        elif kind in ("ac_truth", "veh_truth"):
            out += self._mobile_truth(msg, log_ns, "aircraft" if kind == "ac_truth" else "vehicle")
        elif kind in ("ac_estimate", "veh_estimate"):
            out += self._mobile_estimate(msg, log_ns, "aircraft" if kind == "ac_estimate" else "vehicle")
        self.count += len(out)
        return out

    def _mobile_truth(self, msg: dict, log_ns: int, role: str) -> list[tuple[str, str, dict]]:
        """An aircraft's or a ground vehicle's truth: a cube and its transform."""
        name = msg["src"]
        self.ac_truth[(role, name)] = (msg["t_s"], msg["pos_m"])
        ent = _empty_entity(log_ns, f"{role}/{name}/truth")
        ent["cubes"].append({"pose": {"position": _vec(msg["pos_m"]), "orientation": dict(IDENTITY)},
                             "size": _vec([5.0, 5.0, 5.0]), "color": _color(COLORS["ac_truth"])})
        out = [(TF_TOPIC, "foxglove.FrameTransform", _tf(log_ns, f"{name}_truth", msg["pos_m"])),
               (SCENE_TOPIC, "foxglove.SceneUpdate", {"deletions": [], "entities": [ent]})]
        if self.site is not None:
            out.append((fix_topic(role, name, "truth"), "foxglove.LocationFix",
                        location_fix(self.site, log_ns, f"{name}_truth", msg["pos_m"], color=COLORS["ac_truth"])))
        return out

    def _mobile_estimate(self, msg: dict, log_ns: int, role: str) -> list[tuple[str, str, dict]]:
        """An aircraft's or a ground vehicle's estimate: ellipsoid, label, transform and the numbers
        (``larns.AircraftEstimate``) against its latest truth within 0.5 s."""
        name, algo = msg["src"], msg["algo"]
        size, q = ellipsoid(msg["cov_m2"])
        ent = _empty_entity(log_ns, f"{role}/{name}/{algo}")
        ent["spheres"].append({"pose": {"position": _vec(msg["pos_m"]), "orientation": q}, "size": size,
                               "color": _color(COLORS["aircraft"])})
        ent["texts"].append(_label(msg["pos_m"], f"{name} {algo}", COLORS["aircraft"][:3] + (1.0,)))
        tr = self.ac_truth.get((role, name))
        truth = tr[1] if tr is not None and abs(tr[0] - msg["t_s"]) < 0.5 else None
        rec = {"t_s": _f(msg["t_s"]), "name": name, "algo": algo, **_numbers(msg["pos_m"], msg["cov_m2"], truth)}
        if "n_updates" in msg:
            rec["n_updates"] = int(msg["n_updates"])
        out = [(TF_TOPIC, "foxglove.FrameTransform", _tf(log_ns, f"{name}_{algo}", msg["pos_m"])),
               (SCENE_TOPIC, "foxglove.SceneUpdate", {"deletions": [], "entities": [ent]}),
               (f"larns/foxglove/{role}/{name}/{algo}", "larns.AircraftEstimate", rec)]
        if self.site is not None:
            out.append((fix_topic(role, name, algo), "foxglove.LocationFix",
                        location_fix(self.site, log_ns, f"{name}_{algo}", msg["pos_m"], msg["cov_m2"],
                                     COLORS["aircraft"])))
        return out

    def convert_bytes(self, key: str, data: bytes, log_ns: int) -> list[tuple[str, str, bytes]]:
        """Wire bytes -> [(topic, schema name, JSON bytes)]; anything undecodable yields nothing."""
        if not converts(key):
            return []
        from net.messages import MessageError

        from ..log.series import decode

        try:
            msg, _ = decode(data)
        except MessageError:
            return []
        return [(t, s, dumps(d)) for t, s, d in self.convert(msg, log_ns)]


def converts(key: str) -> bool:
    """Whether the view converts messages of this key (estimates and truths)."""
    tail = key.rsplit("/", 2)
    return key.endswith("/estimate") or key.endswith("/truth") or (len(tail) == 3 and tail[1] == "estimate")


def dumps(d: dict) -> bytes:
    """Strict JSON (raises ValueError on NaN / infinity)."""
    return json.dumps(d, allow_nan=False, separators=(",", ":")).encode()


def schema_for(name: str) -> tuple[str, bytes]:
    return name, SCHEMA_BYTES[name]


def iter_json(msgs, site=None) -> Iterator[tuple[int, int, str, str, bytes]]:
    """(log_time, publish_time, topic, schema name, JSON bytes) for recorded wire messages (with
    ``foxglove.LocationFix`` channels when a ``site`` is given)."""
    from ..log.series import decode_all

    view = FoxgloveView(site)
    for m, msg in decode_all(m for m in msgs if converts(m.topic)):
        if msg is not None:
            for t, s, d in view.convert(msg, m.log_time):
                yield m.log_time, m.publish_time, t, s, dumps(d)


# --------------------------------------------------------------------------- larns export

def recording_site(logs, scenario: str | None = None):
    """The site (:class:`nav.site.Site`) of a recording: ``scenario`` (a name or TOML path) when
    given, else the ``site`` entry of its ``larns`` metadata (the recorder writes it), else the
    ``[site]`` of the scenario its metadata names, if that loads; None when there is none.
    A ``scenario`` that does not load raises :class:`net.scenario.ScenarioError`."""
    from nav.site import Site
    from net.scenario import ScenarioError, load

    if scenario is not None:
        return load(scenario).site
    md = {k: v for lg in reversed(list(logs)) for k, v in lg.metadata.get("larns", {}).items()}
    if md.get("site"):
        try:
            return Site.from_json(md["site"])
        except (ValueError, KeyError, TypeError):
            pass
    if md.get("scenario"):
        try:
            return load(md["scenario"]).site
        except ScenarioError:
            return None
    return None


def export(paths, output: str | Path, site=None) -> dict:
    """Copy the recording(s) (wire channels untouched) and add the Foxglove JSON channels
    (existing ``larns/foxglove/**`` channels are regenerated); with a ``site``
    (:func:`recording_site`) also the ``foxglove.LocationFix`` channels."""
    import heapq

    from ..log import LogWriter, Msg, merge, read_logs

    logs = read_logs(paths)
    msgs = [m for m in merge(logs) if not m.topic.startswith("larns/foxglove/")]
    md = {name: dict(v) for lg in reversed(logs) for name, v in lg.metadata.items()}
    md["larns_export"] = {"sources": ",".join(str(lg.path) for lg in logs), "foxglove": "json"}
    if site is not None:
        md.setdefault("larns", {})["site"] = site.to_json()
    extra = [Msg(t, lt, pt, 0, b, "json", s) for lt, pt, t, s, b in iter_json(msgs, site)]
    n_json = 0
    with LogWriter(output, md, library="larns export") as w:
        for m in heapq.merge(msgs, extra, key=lambda m: m.log_time):
            if m.encoding == "json" and m.schema in SCHEMA_BYTES:
                w.write(m.topic, m.data, m.log_time, m.publish_time, "json", schema_for(m.schema))
                n_json += 1
            else:
                schema = None
                if m.schema:
                    for lg in logs:
                        for name, _enc, data in lg.schemas.values():
                            if name == m.schema:
                                schema = (name, data)
                w.write(m.topic, m.data, m.log_time, m.publish_time, m.encoding, schema)
    return {"output": str(output), "messages": len(msgs), "json_messages": n_json,
            "complete_inputs": all(lg.complete for lg in logs)}
