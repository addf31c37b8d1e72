"""Spatial tiles of the air on the wire: a station's nav is published on a key that names the tile of
its physical position, and a station process subscribes only to the tiles its radio can reach.

Key: ``larns/station/<id>/nav/<tile>``, the tile chunk ``<ix>_<iy>`` (e.g. ``3_-1``): the square
``[ix T, (ix + 1) T) x [iy T, (iy + 1) T)`` of side ``T`` (``[radio] tile_m``) in the x-y plane of
the emulator's world frame (the true positions the channel works with, ``Scenario.pos_m``). The
tile is part of the emulated air, like the channel's link test: it comes from the scenario's true
position, never from an estimate, and no estimator sees it (``phy`` and the key are stripped
before the core gets a message).

Subscription rule: a station at true position ``p`` subscribes to every tile that intersects the
disc of radius ``R`` around ``p``'s x-y, with ``R`` = :func:`net.radio.max_range_m` between its own
antenna height and the highest antenna of the scenario (radio horizon and link budget; the path
loss only grows with distance and falls with either height, and terrain only removes links). A
link the radio allows has a straight-line length at most ``R``, and the x-y distance of any frame
is at most that length, so the set is a superset of the station's real neighbours: no link the
radio allows is ever missing on the wire. It also subscribes to the tile-less key
``larns/station/*/nav`` that no live station uses, so a recording made before tiles, replayed
(``larns replay``), still reaches it.

Without a ``[radio]`` section every station hears every other: the tile is ``0_0`` for everyone
and a station subscribes to all tiles (``larns/station/*/nav/**``), as the recorder, the viewer,
the monitor, the aircraft and the vehicle always do. ``LARNS_NAV_TILES=off`` in a station's
environment makes it subscribe to all tiles too (the comparison of ``larns bench wire``).

Default ``T``: half the longest link between two antennas at ``[radio] antenna_height_m`` above
the ground (from the radio parameters alone, so every process of a fleet derives the same tiles
whatever stations it knows of). With ``T = R / 2`` a station subscribes to some 20-25 tiles that
cover about twice its reach disc's area; bigger tiles mean fewer subscriptions and more unwanted navs.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from .radio import RadioParams, _heights, max_range_m

ALL_NAVS = "larns/station/*/nav/**"  # every tile and the tile-less key of recordings before tiles
UNTILED_NAVS = "larns/station/*/nav"
TILE_FRACTION = 0.5  # default tile side / the longest link at the nominal antenna height
REACH_MARGIN = 1e-6  # relative margin on the reach disc (float rounding of the radio's own test)
_CHUNK = re.compile(r"^(-?\d+)_(-?\d+)$")


def tiles_enabled() -> bool:
    """``LARNS_NAV_TILES`` (default on): off, 0, no or false subscribes a station to every tile."""
    return os.environ.get("LARNS_NAV_TILES", "on").lower() not in ("off", "0", "no", "false")


def default_tile_m(radio: RadioParams) -> float:
    """Half the longest link between two antennas ``antenna_height_m`` above flat ground, whole metres."""
    h = max(float(radio.antenna_height_m), 0.1)
    return float(max(1.0, round(TILE_FRACTION * max_range_m(radio, h, h))))


def tile_size_m(radio: RadioParams | None) -> float:
    """The tile side ``T`` (m); infinite without a radio (one tile, ``0_0``)."""
    if radio is None:
        return math.inf
    return float(radio.tile_m) if radio.tile_m is not None else default_tile_m(radio)


def tile_of(pos_m, size_m: float) -> tuple[int, int]:
    """The tile ``(ix, iy)`` of a position (3,) for tiles of side ``size_m``."""
    if not math.isfinite(size_m):
        return (0, 0)
    p = np.asarray(pos_m, float)
    return (int(math.floor(p[0] / size_m)), int(math.floor(p[1] / size_m)))


def tile_chunk(tile: tuple[int, int]) -> str:
    """``(3, -1)`` -> ``"3_-1"``: one key chunk (no ``*``, ``$``, ``?``, ``#``, ``/``)."""
    return f"{int(tile[0])}_{int(tile[1])}"


def parse_tile(chunk: str) -> tuple[int, int] | None:
    """Inverse of :func:`tile_chunk`; None if ``chunk`` is not a tile."""
    m = _CHUNK.match(str(chunk))
    return None if m is None else (int(m[1]), int(m[2]))


def nav_key(station_id: int, tile: tuple[int, int]) -> str:
    return f"larns/station/{int(station_id)}/nav/{tile_chunk(tile)}"


def tiles_within(center_m, radius_m: float, size_m: float) -> list[tuple[int, int]]:
    """Every tile of side ``size_m`` whose square intersects the disc of ``radius_m`` around the x-y of
    ``center_m`` (a closed disc: a tile touching it counts)."""
    cx, cy = float(center_m[0]), float(center_m[1])
    out = []
    for ix in range(math.floor((cx - radius_m) / size_m), math.floor((cx + radius_m) / size_m) + 1):
        dx = max(ix * size_m - cx, 0.0, cx - (ix + 1) * size_m)  # x distance from the centre to the square
        for iy in range(math.floor((cy - radius_m) / size_m), math.floor((cy + radius_m) / size_m) + 1):
            dy = max(iy * size_m - cy, 0.0, cy - (iy + 1) * size_m)
            if dx * dx + dy * dy <= radius_m * radius_m:
                out.append((ix, iy))
    return out


@dataclass(frozen=True)
class Tiling:
    """The tiles of one scenario's world: true positions (network frame, ``Scenario.pos_m``) and radio."""

    radio: RadioParams | None
    size_m: float
    top_height_m: float  # the highest antenna above the ground among the scenario's stations

    @classmethod
    def of(cls, scn) -> "Tiling":
        radio = scn.channel.radio
        if radio is None:
            return cls(None, math.inf, 0.0)
        top = float(np.max(_heights(np.asarray(scn.pos_m, float), radio)))
        return cls(radio, tile_size_m(radio), top)

    def tile(self, pos_m) -> tuple[int, int]:
        return tile_of(pos_m, self.size_m)

    def nav_key(self, station_id: int, pos_m) -> str:
        """The key of station ``station_id``'s navs, sent from true position ``pos_m``."""
        return nav_key(station_id, self.tile(pos_m))

    def reach_m(self, pos_m) -> float:
        """The longest link a receiver at ``pos_m`` can have with any station of the scenario (inf
        without a radio)."""
        if self.radio is None:
            return math.inf
        h_own = float(_heights(np.asarray(pos_m, float), self.radio))
        return max_range_m(self.radio, h_own, max(self.top_height_m, h_own)) * (1.0 + REACH_MARGIN) + 1e-3

    def subscription_tiles(self, pos_m) -> list[tuple[int, int]] | None:
        """The tiles a station at ``pos_m`` subscribes to; None: all of them."""
        if self.radio is None or not tiles_enabled():
            return None
        return tiles_within(pos_m, self.reach_m(pos_m), self.size_m)

    def nav_subscriptions(self, pos_m) -> list[str]:
        """The key expressions of the navs a station at ``pos_m`` subscribes to."""
        tiles = self.subscription_tiles(pos_m)
        if tiles is None:
            return [ALL_NAVS]
        return [f"larns/station/*/nav/{tile_chunk(t)}" for t in tiles] + [UNTILED_NAVS]


def station_nav_keys(scn, ids) -> dict[int, str]:
    """``{id: nav key}`` of stations ``ids`` of scenario ``scn`` (an id it does not list: at the
    hot-joiner's position, :func:`net.scenario.joiner_position`)."""
    from .scenario import joiner_position

    t = Tiling.of(scn)
    out = {}
    for i in map(int, ids):
        try:
            out[i] = t.nav_key(i, joiner_position(scn, i))
        except (ValueError, OSError):  # a joiner the scenario cannot place (ScenarioError): no key
            continue
    return out
