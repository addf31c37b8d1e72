"""A recording on the map: the surveyed stations and the tracks as GeoJSON (RFC 7946), KML and CSV
(``larns export --geojson / --kml / --csv``).

Pure functions of a decoded recording (:class:`larns.log.series.Recording`) and its site
(:class:`nav.site.Site`, the scenario's ``[site]`` tied to the network frame):

* each station's **last estimate** as a Point with its sigmas (network frame and East-North-Up in
  the tangent plane at the point) and its 2-sigma horizontal error ellipse (semi-axes, azimuth of
  the major axis) as properties, plus a Polygon approximating that ellipse (``ELLIPSE_POINTS``
  vertices, counter-clockwise; built in the ENU plane at the site's origin);
* the **tracks** of every aircraft algorithm and vehicle as LineStrings;
* the **truth** (stations, aircraft and vehicle tracks) as separate features;

every feature has a ``kind`` property (``station``, ``station_ellipse``, ``station_truth``,
``aircraft_track``, ``aircraft_truth``, ``vehicle_track``, ``vehicle_truth``). Coordinates are
``[longitude, latitude, ellipsoidal height]`` with 9 decimals of a degree (0.1 mm) and 4 of a metre.
The CSV needs no site: id, state, time, network-frame coordinates and sigmas, and latitude,
longitude, height and the ENU sigmas when there is a site.
"""

from __future__ import annotations

import csv
import io
import math
from typing import Any
from xml.sax.saxutils import escape

import numpy as np

from nav.site import Site, ellipse_ring, horizontal_ellipse

K_SIGMA = 2.0
ELLIPSE_POINTS = 36
MIN_SEMI_AXIS_M = 1e-3  # a frame station's zero covariance still gets a (1 mm) ring
DEG_DECIMALS, M_DECIMALS = 9, 4


def _pos(lon: float, lat: float, h: float) -> list[float]:
    return [round(float(lon), DEG_DECIMALS), round(float(lat), DEG_DECIMALS), round(float(h), M_DECIMALS)]


def _r(x: float, nd: int = 4) -> float | None:
    x = float(x)
    return round(x, nd) if math.isfinite(x) else None


def _line(site: Site, pos_n: np.ndarray) -> list[list[float]]:
    lat, lon, h = site.net_to_geodetic(pos_n)
    return [_pos(*p) for p in zip(lon, lat, h)]


def station_rows(rec, site: Site | None = None) -> list[dict[str, Any]]:
    """One row per station with an estimate: its last estimate (network frame), sigmas, and with a
    ``site`` its geodetic position, ENU sigmas and the 2-sigma horizontal ellipse; ``truth_m`` (3,)
    or None."""
    rows = []
    for sid in sorted(rec.stations):
        s = rec.stations[sid]
        e = s.last
        if e is None:
            continue
        pos, cov = np.asarray(e["pos_m"], float), np.asarray(e["cov_m2"], float)
        var = np.maximum(np.diag(cov), 0.0)
        row: dict[str, Any] = {"id": sid, "state": e["state"], "t_s": float(e["t_s"]), "n_updates": int(e["n_updates"]),
                               "pos_m": pos, "cov_m2": cov, "sigma_m": np.sqrt(var), "truth_m": s.truth_m}
        if site is not None:
            lat, lon, h = site.net_to_geodetic(pos)
            enu = site.net_cov_to_enu(cov, lat, lon)
            a, b, az = horizontal_ellipse(enu[:2, :2], K_SIGMA)
            row.update(lat_deg=float(lat), lon_deg=float(lon), h_m=float(h), cov_enu_m2=enu,
                       sigma_enu_m=np.sqrt(np.maximum(np.diag(enu), 0.0)), ellipse=(a, b, az))
        rows.append(row)
    return rows


def _station_features(site: Site, row: dict) -> list[dict]:
    sid = row["id"]
    sx, sy, sz = row["sigma_m"]
    se, sn, su = row["sigma_enu_m"]
    a, b, az = row["ellipse"]
    props = {"kind": "station", "id": sid, "state": row["state"], "t_s": _r(row["t_s"], 3),
             "n_updates": row["n_updates"], "x_m": _r(row["pos_m"][0]), "y_m": _r(row["pos_m"][1]),
             "z_m": _r(row["pos_m"][2]), "sigma_x_m": _r(sx), "sigma_y_m": _r(sy), "sigma_z_m": _r(sz),
             "sigma_e_m": _r(se), "sigma_n_m": _r(sn), "sigma_u_m": _r(su),
             "ellipse_k_sigma": K_SIGMA, "ellipse_semi_major_m": _r(a), "ellipse_semi_minor_m": _r(b),
             "ellipse_azimuth_deg": _r(az, 2)}
    out = [{"type": "Feature", "geometry": {"type": "Point", "coordinates": _pos(row["lon_deg"], row["lat_deg"],
                                                                                 row["h_m"])},
            "properties": props}]
    center_f = site.net_to_frame(row["pos_m"])
    en = site.net_cov_to_enu(row["cov_m2"])[:2, :2] + MIN_SEMI_AXIS_M ** 2 / K_SIGMA ** 2 * np.eye(2)
    ring = ellipse_ring(site, center_f, en, K_SIGMA, ELLIPSE_POINTS)
    out.append({"type": "Feature",
                "geometry": {"type": "Polygon", "coordinates": [[_pos(*p) for p in ring]]},
                "properties": {"kind": "station_ellipse", "id": sid, "k_sigma": K_SIGMA,
                               "semi_major_m": _r(a), "semi_minor_m": _r(b), "azimuth_deg": _r(az, 2)}})
    if row["truth_m"] is not None:
        lat, lon, h = site.net_to_geodetic(np.asarray(row["truth_m"], float))
        err = np.asarray(row["pos_m"]) - np.asarray(row["truth_m"], float)
        err_enu = site.net_cov_to_enu(np.outer(err, err), lat, lon)
        out.append({"type": "Feature", "geometry": {"type": "Point", "coordinates": _pos(lon, lat, h)},
                    "properties": {"kind": "station_truth", "id": sid,
                                   "err_h_m": _r(math.sqrt(max(err_enu[0, 0] + err_enu[1, 1], 0.0))),
                                   "err_v_m": _r(math.sqrt(max(err_enu[2, 2], 0.0)))}})
    return out


def _tracks(rec) -> list[tuple[str, dict, np.ndarray, np.ndarray]]:
    """(kind, properties, t_s (K,), pos_m (K, 3)) of every aircraft / vehicle estimate track and truth."""
    out = []
    for name in sorted(rec.aircraft):
        a = rec.aircraft[name]
        for algo in a.algos:
            tr = a.track(algo)
            out.append(("aircraft_track", {"name": name, "algo": algo}, tr["t_s"], tr["pos_m"]))
        tt = a.truth_track()
        if tt is not None:
            out.append(("aircraft_truth", {"name": name}, tt["t_s"], tt["pos_m"]))
    for name in sorted(rec.vehicles):
        v = rec.vehicles[name]
        est = sorted(v.estimates, key=lambda e: e["t_s"])
        if est:
            algos = sorted({str(e.get("algo", "")) for e in est})
            for algo in algos:
                rows = [e for e in est if str(e.get("algo", "")) == algo]
                out.append(("vehicle_track", {"name": name, "algo": algo}, np.array([e["t_s"] for e in rows]),
                            np.array([e["pos_m"] for e in rows], float)))
        truth = [v.truths[t] for t in sorted(v.truths)]
        if truth:
            out.append(("vehicle_truth", {"name": name}, np.array([e["t_s"] for e in truth]),
                        np.array([e["pos_m"] for e in truth], float)))
    return out


def _finite(t_s: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    ok = np.all(np.isfinite(pos), axis=-1) & np.isfinite(t_s)
    return t_s[ok], pos[ok]


def geojson(rec, site: Site) -> dict:
    """The recording on the map as a GeoJSON FeatureCollection (module docstring)."""
    feats: list[dict] = []
    for row in station_rows(rec, site):
        feats += _station_features(site, row)
    for kind, props, t_s, pos in _tracks(rec):
        t_s, pos = _finite(t_s, pos)
        if len(pos) < 2:
            continue
        feats.append({"type": "Feature", "geometry": {"type": "LineString", "coordinates": _line(site, pos)},
                      "properties": {"kind": kind, **props, "points": int(len(pos)), "t_start_s": _r(t_s[0], 3),
                                     "t_end_s": _r(t_s[-1], 3)}})
    return {"type": "FeatureCollection", "features": feats}


_KML_STYLES = {"station": "ff0000ff", "station_ellipse": "ffff7f00", "station_truth": "ff00cc00",
               "aircraft_track": "ff0099ff", "aircraft_truth": "ff00cc00", "vehicle_track": "ffcc00cc",
               "vehicle_truth": "ff00cc00"}


def _kml_coords(coords) -> str:
    return " ".join(f"{c[0]:.9f},{c[1]:.9f},{c[2]:.4f}" for c in coords)


def kml(rec, site: Site, name: str = "larns") -> str:
    """The same features as :func:`geojson` as a KML 2.2 document (one folder per ``kind``).
    KML altitudes are ``absolute``; ours are WGS84 ellipsoidal heights (KML reads them above mean sea
    level: they differ by the local geoid undulation)."""
    folders: dict[str, list[str]] = {}
    for f in geojson(rec, site)["features"]:
        p, g = f["properties"], f["geometry"]
        label = f"S{p['id']}" if "id" in p else f"{p.get('name', '')} {p.get('algo', 'truth')}".strip()
        data = "".join(f'<Data name="{escape(str(k))}"><value>{escape(str(v))}</value></Data>' for k, v in p.items())
        if g["type"] == "Point":
            geom = (f"<Point><altitudeMode>absolute</altitudeMode><coordinates>{_kml_coords([g['coordinates']])}"
                    "</coordinates></Point>")
        elif g["type"] == "LineString":
            geom = (f"<LineString><altitudeMode>absolute</altitudeMode><coordinates>{_kml_coords(g['coordinates'])}"
                    "</coordinates></LineString>")
        else:
            geom = ("<Polygon><altitudeMode>absolute</altitudeMode><outerBoundaryIs><LinearRing><coordinates>"
                    f"{_kml_coords(g['coordinates'][0])}</coordinates></LinearRing></outerBoundaryIs></Polygon>")
        folders.setdefault(p["kind"], []).append(
            f"<Placemark><name>{escape(label)}</name><styleUrl>#{p['kind']}</styleUrl>"
            f"<ExtendedData>{data}</ExtendedData>{geom}</Placemark>")
    styles = "".join(f'<Style id="{k}"><LineStyle><color>{c}</color><width>2</width></LineStyle>'
                     f'<PolyStyle><color>{"40" + c[2:]}</color></PolyStyle>'
                     f'<IconStyle><color>{c}</color></IconStyle></Style>' for k, c in _KML_STYLES.items())
    body = "".join(f"<Folder><name>{escape(k)}</name>{''.join(v)}</Folder>" for k, v in folders.items())
    return ('<?xml version="1.0" encoding="UTF-8"?>\n<kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
            f"<name>{escape(name)}</name>{styles}{body}</Document></kml>\n")


CSV_COLUMNS = ["id", "state", "t_s", "n_updates", "x_m", "y_m", "z_m", "sigma_x_m", "sigma_y_m", "sigma_z_m"]
CSV_SITE_COLUMNS = ["lat_deg", "lon_deg", "h_m", "sigma_e_m", "sigma_n_m", "sigma_u_m"]


def csv_text(rec, site: Site | None = None) -> str:
    """The surveyed coordinates: one row per station (its last estimate); network frame, metres;
    with a site also latitude, longitude (degrees), ellipsoidal height and the ENU sigmas."""
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS + (CSV_SITE_COLUMNS if site is not None else []))
    for r in station_rows(rec, site):
        row = [r["id"], r["state"], f"{r['t_s']:.3f}", r["n_updates"], *(f"{v:.4f}" for v in r["pos_m"]),
               *(f"{v:.4f}" for v in r["sigma_m"])]
        if site is not None:
            row += [f"{r['lat_deg']:.9f}", f"{r['lon_deg']:.9f}", f"{r['h_m']:.4f}",
                    *(f"{v:.4f}" for v in r["sigma_enu_m"])]
        w.writerow(row)
    return buf.getvalue()
