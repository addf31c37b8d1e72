"""Every reproducible random stream of a LARNS world, named in one place.

A stream is a ``numpy.random.Generator`` seeded by a key ``[world seed, who, ...]``: the in-process
simulator and the Zenoh processes derive the same keys, so they draw the same world, and one part's
draws never shift another's. ``who`` is a station id (its streams are told apart by a purpose) or the
tag of a mobile process (far above any station id); further key parts (a name, a block, an epoch) are
the caller's.
"""

from __future__ import annotations

import numpy as np

# a station's streams: [seed, station id, purpose] (net.channel.station_rng)
CLOCK, COARSE_FIX, AIR, WIRE = 0, 1, 2, 3
SLOTS = 4  # its distributed slot assignment's choices (stations/slots.py, via stations/core.py)

# the mobile processes' streams: [seed, tag, name, ...]
AIRCRAFT_RADIO = 0xA1C    # the radio aircraft's channel noise (aircraft/radio_core.py)
AIRCRAFT_INS = 0x1A5      # the inertial aircraft's channel noise (aircraft/ins_core.py)
AIRCRAFT_INS_IMU = 0x1B0  # its IMU blocks
AIRCRAFT_TRIAD = 0x7A1    # the triad aircraft's world (aircraft/world/triad.py, keyed further by part)
VEHICLE = 0x7E1           # the ground vehicle's world (vehicle/core.py)


def name_key(name: str) -> int:
    """A process name as a key part (the sum of its code points)."""
    return sum(map(ord, name))


def key(seed: int, tag: int, *parts: int) -> list[int]:
    """The key of a stream: ``[seed, tag, *parts]`` as ints."""
    return [int(seed), int(tag), *(int(p) for p in parts)]


def rng(seed: int, tag: int, *parts: int) -> np.random.Generator:
    """The stream of :func:`key`."""
    return np.random.default_rng(key(seed, tag, *parts))
