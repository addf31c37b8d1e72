"""The scenario's ``[aircraft]`` table, parsed (format in docs/aircraft.md)."""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from .navigator.radio.models import ALGOS
from .navigator.radio.tuning import Tuning
from .world.clock import ReceiverClock

_KNOWN = {"name", "algos", "rate_hz", "sync", "sigma_m", "df_hz", "lambda_m", "tau0_s", "height_m",
          "trajectory", "tuning", "turn", "hover", "bench", "crlb", "init_sigma_m", "imu",
          "satellites"}


@dataclass
class AircraftConfig:
    name: str
    stations_m: np.ndarray  # (m, 3) network frame, scenario order
    centre_m: np.ndarray  # (3,) centroid of the stations
    algos: list[str]
    rate_hz: float
    sync: bool  # True: every station every epoch (seed 001); False: TDMA slots
    sigma_m: float
    clock: ReceiverClock
    height_m: float | None  # None: 3 deg glide path
    trajectory: dict[str, Any]
    trajectories: dict[str, dict[str, Any]]  # per-kind defaults for the bench (turn, hover)
    tuning: Tuning
    bench: dict[str, Any] = field(default_factory=dict)
    crlb: dict[str, Any] = field(default_factory=dict)
    init_sigma_m: float | None = None  # coarse external fix of the start point (node); None: LSQ start
    imu: str | None = None  # IMU preset of the inertial aircraft (ins-ekf, docs/ins.md)
    satellites: int | None = None  # the triad's satellites (algo triad, docs/triad.md)
    # the scenario's [radio] in the network frame (net/radio.py), world side: which stations the
    # aircraft hears and how noisy each reception is; None: every station, noise sigma_m
    radio: Any = None


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
    traj = dict(a.get("trajectory", {"kind": "hover", "distance_m": 1000.0}))
    return AircraftConfig(
        name=str(a.get("name", "ac1")),
        stations_m=np.asarray(sc.pos_m, dtype=float),
        centre_m=np.asarray(sc.pos_m, dtype=float).mean(axis=0),
        algos=algos,
        rate_hz=float(a.get("rate_hz", 100.0)),
        sync=bool(a.get("sync", True)),
        sigma_m=sigma,
        clock=ReceiverClock(float(a.get("df_hz", 20.0)), float(a.get("lambda_m", 0.03)), float(a.get("tau0_s", 0.0))),
        height_m=None if h is None else float(h),
        trajectory=traj,
        trajectories={"turn": dict(a.get("turn", {})), "hover": dict(a.get("hover", {}))},
        tuning=tuning,
        bench=dict(a.get("bench", {})),
        crlb=dict(a.get("crlb", {})),
        init_sigma_m=None if a.get("init_sigma_m") is None else float(a["init_sigma_m"]),
        imu=None if a.get("imu") is None else str(a["imu"]),
        satellites=None if a.get("satellites") is None else int(a["satellites"]),
        radio=getattr(sc.channel, "radio", None),
    )
