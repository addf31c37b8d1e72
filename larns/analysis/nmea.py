"""NMEA 0183 sentences of a position track, for tools that expect a GPS receiver
(``larns export --nmea OUT``): one ``$GPGGA`` and one ``$GPRMC`` per estimate.

Plain formatting (no NMEA library): ``$<body>*<checksum>`` where the checksum is the XOR of the body's
bytes as two upper-case hex digits. The time of a fix is the fleet epoch plus the fleet time of the
estimate (UTC). Heights are WGS84 ellipsoidal: GGA's altitude field carries the ellipsoidal height
and its geoid separation is 0 (no geoid model here). Speed and course over ground come from the
horizontal displacement between consecutive fixes; the fix quality is 1 and HDOP is the horizontal
sigma in metres divided by 5 m (an HDOP-like figure, clipped to 0.1..99.9).
"""

from __future__ import annotations

import math
from datetime import datetime, timezone
from functools import reduce

import numpy as np

KNOTS_PER_M_S = 3600.0 / 1852.0
UERE_M = 5.0  # the metres of horizontal sigma taken as one unit of HDOP


def checksum(body: str) -> str:
    """The NMEA checksum of a sentence body (between ``$`` and ``*``): XOR of its bytes, 2 hex digits."""
    return f"{reduce(lambda a, c: a ^ c, body.encode('ascii'), 0):02X}"


def sentence(body: str) -> str:
    return f"${body}*{checksum(body)}"


def valid(line: str) -> bool:
    """Whether ``line`` is ``$body*CS`` with the right checksum."""
    line = line.strip()
    if not line.startswith("$") or len(line) < 4 or line[-3] != "*":
        return False
    return checksum(line[1:-3]) == line[-2:].upper()


def _degrees_minutes(value_deg: float, width: int, pos: str, neg: str) -> tuple[str, str]:
    """NMEA ``(d)ddmm.mmmmm`` with ``width`` degree digits and the hemisphere letter."""
    a = abs(value_deg)
    d = int(a)
    m = (a - d) * 60.0
    if round(m, 5) >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:0{width}d}{m:08.5f}", pos if value_deg >= 0 else neg


def _lat(lat_deg: float) -> tuple[str, str]:
    return _degrees_minutes(lat_deg, 2, "N", "S")


def _lon(lon_deg: float) -> tuple[str, str]:
    return _degrees_minutes(lon_deg, 3, "E", "W")


def _utc(unix_s: float) -> datetime:
    return datetime.fromtimestamp(unix_s, tz=timezone.utc)


def gga(unix_s: float, lat_deg: float, lon_deg: float, h_m: float, n_used: int = 0, sigma_h_m: float = 5.0) -> str:
    t = _utc(unix_s)
    la, ns = _lat(lat_deg)
    lo, ew = _lon(lon_deg)
    hdop = min(max(sigma_h_m / UERE_M, 0.1), 99.9)
    body = (f"GPGGA,{t:%H%M%S}.{t.microsecond // 10000:02d},{la},{ns},{lo},{ew},1,{n_used:02d},{hdop:.1f},"
            f"{h_m:.2f},M,0.00,M,,")
    return sentence(body)


def rmc(unix_s: float, lat_deg: float, lon_deg: float, speed_m_s: float = 0.0, course_deg: float = 0.0) -> str:
    t = _utc(unix_s)
    la, ns = _lat(lat_deg)
    lo, ew = _lon(lon_deg)
    body = (f"GPRMC,{t:%H%M%S}.{t.microsecond // 10000:02d},A,{la},{ns},{lo},{ew},{speed_m_s * KNOTS_PER_M_S:.2f},"
            f"{course_deg % 360.0:.1f},{t:%d%m%y},,,A")
    return sentence(body)


def track_sentences(site, epoch_unix_s: float, t_s, pos_n, cov_n=None, n_used: int = 0) -> list[str]:
    """GGA + RMC per fix of a network-frame track: ``t_s`` (K,) fleet seconds, ``pos_n`` (K, 3),
    ``cov_n`` (K, 3, 3) or None, on ``site`` (:class:`nav.site.Site`)."""
    t_s = np.asarray(t_s, float)
    pos_n = np.asarray(pos_n, float)
    lat, lon, h = site.net_to_geodetic(pos_n)
    enu = site.frame_to_enu(site.net_to_frame(pos_n))
    out = []
    for k in range(len(t_s)):
        sig = 5.0
        if cov_n is not None:
            c = site.net_cov_to_enu(np.asarray(cov_n[k], float))
            sig = math.sqrt(max(c[0, 0] + c[1, 1], 0.0))
        speed, course = 0.0, 0.0
        if k > 0 and t_s[k] > t_s[k - 1]:
            d = enu[k, :2] - enu[k - 1, :2]
            speed = float(np.hypot(*d) / (t_s[k] - t_s[k - 1]))
            course = math.degrees(math.atan2(d[0], d[1])) % 360.0
        u = epoch_unix_s + float(t_s[k])
        out += [gga(u, float(lat[k]), float(lon[k]), float(h[k]), n_used, sig),
                rmc(u, float(lat[k]), float(lon[k]), speed, course)]
    return out
