"""The scenario's ``[aircraft]`` table, parsed (format in docs/aircraft.md), split into what the world
knows and what the navigator knows.

* :class:`AircraftWorldConfig`: the world's truth and the simulation around the aircraft - the
  scenario's true station positions and their centroid, the receiver clock, the timing noise, the
  ``[radio]`` channel, the trajectory and its height, the benches' epoch rate. Read by world-side
  code only: the live cores' channel layer and truth (``aircraft/world/``), the Monte Carlo drivers
  and the benches.
* :class:`NavigatorConfig`: what the aircraft's navigator may know - the algorithms it runs, its
  filter tuning, its nominal range sigma, the width of its start prior, its IMU's datasheet, the
  satellites it tracks, and the field's bounds as the operator planned the deployment
  (:attr:`NavigatorConfig.field_bounds`). No station position and nothing else true: the navigator
  learns where the stations are from their broadcasts alone. ``aircraft/navigator/**`` is handed
  this part only (``tests/test_architecture.py`` checks the type and the code).
* :class:`AircraftConfig`: both parts, the aircraft's name and the benches' settings.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from net.plausible import NavBounds

from .navigator.radio.models import ALGOS
from .navigator.radio.tuning import Tuning
from .world.clock import ReceiverClock

_KNOWN = {"name", "algos", "rate_hz", "sync", "sigma_m", "df_hz", "lambda_m", "tau0_s", "height_m",
          "trajectory", "tuning", "turn", "hover", "bench", "crlb", "init_sigma_m", "imu",
          "satellites"}


@dataclass(frozen=True)
class AircraftWorldConfig:
    """The world around the aircraft: truth and the channel that measures it."""

    stations_m: np.ndarray  # (m, 3) the stations' TRUE positions, network frame, scenario order
    centre_m: np.ndarray  # (3,) centroid of the true positions (the trajectories are laid out around it)
    clock: ReceiverClock  # the aircraft's receiver clock as it runs
    sigma_m: float  # one-way timing noise drawn on every pseudorange, m (with [radio]: each link's floor)
    rate_hz: float  # the benches' epochs per second (the live radio core samples its track at it, >= 10 Hz)
    sync: bool  # True: every station every epoch (seed 001); False: TDMA slots
    height_m: float | None  # None: 3 deg glide path
    trajectory: dict[str, Any]  # what the live aircraft flies ([aircraft.trajectory])
    trajectories: dict[str, dict[str, Any]]  # per-kind defaults for the bench (turn, hover)
    # the scenario's [radio] in the network frame (net/radio.py): which stations the aircraft hears
    # and how noisy each reception is; None: every station, noise sigma_m
    radio: Any = None


@dataclass(frozen=True)
class NavigatorConfig:
    """What the aircraft's navigator knows before it hears a broadcast.

    ``field_bounds`` models the operator's deployment plan: the area the stations were put in, as
    the :class:`net.plausible.NavBounds` a broadcast is checked against (a station claiming a
    position farther from the network frame's origin than the planned area's radius plus a coarse
    margin of 1 km is implausible; the clock bounds are the loosest oscillator class). It holds
    scalars only - a radius and the clock and time windows - never a position: the navigator
    learns where the stations are from their broadcasts. The loader builds it from the scenario's
    layout, i.e. the plan is taken to be where the stations stand, to the margin's coarseness."""

    algos: tuple[str, ...]  # the default algorithms of the live aircraft
    tuning: Tuning  # the radio filters' tuning
    sigma_range_m: float  # nominal one-way pseudorange sigma of the receiver (datasheet), m
    field_bounds: NavBounds  # the planned deployment area's plausibility bounds (class docstring)
    init_sigma_m: float | None = None  # only widens the start's wide prior; None: the default prior
    imu: str | None = None  # IMU preset (datasheet) of the inertial aircraft (ins-ekf, docs/ins.md)
    satellites: int | None = None  # the triad's satellites (algo triad, docs/triad.md)


@dataclass(frozen=True)
class AircraftConfig:
    """One aircraft of a scenario: its name, its world, its navigator's knowledge, the benches' settings."""

    name: str
    world: AircraftWorldConfig
    nav: NavigatorConfig
    bench: dict[str, Any] = field(default_factory=dict)
    crlb: dict[str, Any] = field(default_factory=dict)

    def with_tuning(self, tuning: Tuning) -> "AircraftConfig":
        """A copy whose navigator runs ``tuning``."""
        return replace(self, nav=replace(self.nav, tuning=tuning))


def deployment_bounds(stations_m) -> NavBounds:
    """The plausibility bounds of a field deployed at ``stations_m`` (n, 3), network frame: the
    operator's plan of the area (its radius from station 1 plus the 1 km margin), the loosest
    oscillator class and a 1 s cycle (:meth:`net.plausible.NavBounds.of`)."""
    return NavBounds.of(stations_m)


def from_scenario(sc) -> AircraftConfig:
    """Parse ``sc.aircraft`` (a :class:`net.scenario.Scenario`); unknown keys are an error."""
    a = dict(sc.aircraft)
    unknown = set(a) - _KNOWN
    if unknown:
        raise ValueError(f"unknown keys in [aircraft]: {sorted(unknown)}; known: {sorted(_KNOWN)}")
    algos = list(a.get("algos", ["ukf-pr"]))
    bad = [x for x in algos if x not in ALGOS + ("ins-ekf", "triad")]
    if bad:
        raise ValueError(f"unknown algorithms {bad}; choose from {ALGOS}")
    sigma = float(a.get("sigma_m", sc.channel.sigma_d_m))
    tk = dict(a.get("tuning", {}))
    names = {f.name for f in fields(Tuning)}
    if set(tk) - names:
        raise ValueError(f"unknown keys in [aircraft.tuning]: {sorted(set(tk) - names)}")
    tk.setdefault("sigma_m", sigma)
    try:
        tuning = Tuning(**tk)
    except (TypeError, ValueError) as e:
        raise ValueError(f"[aircraft.tuning] {e}") from None
    h = a.get("height_m")
    stations = np.asarray(sc.pos_m, dtype=float)
    world = AircraftWorldConfig(
        stations_m=stations,
        centre_m=stations.mean(axis=0),
        clock=ReceiverClock(float(a.get("df_hz", 20.0)), float(a.get("lambda_m", 0.03)), float(a.get("tau0_s", 0.0))),
        sigma_m=sigma,
        rate_hz=float(a.get("rate_hz", 100.0)),
        sync=bool(a.get("sync", True)),
        height_m=None if h is None else float(h),
        trajectory=dict(a.get("trajectory", {"kind": "hover", "distance_m": 1000.0})),
        trajectories={"turn": dict(a.get("turn", {})), "hover": dict(a.get("hover", {}))},
        radio=getattr(sc.channel, "radio", None),
    )
    nav = NavigatorConfig(
        algos=tuple(algos),
        tuning=tuning,
        sigma_range_m=sigma,
        field_bounds=deployment_bounds(stations),
        init_sigma_m=None if a.get("init_sigma_m") is None else float(a["init_sigma_m"]),
        imu=None if a.get("imu") is None else str(a["imu"]),
        satellites=None if a.get("satellites") is None else int(a["satellites"]),
    )
    return AircraftConfig(name=str(a.get("name", "ac1")), world=world, nav=nav,
                          bench=dict(a.get("bench", {})), crlb=dict(a.get("crlb", {})))
