#!/usr/bin/env python3
"""Consistency of the stations' reported covariance in the datum mode (docs/survey.md, "Heights in the
datum mode"): the in-process simulator with ``[survey] datum = "field"``, per snapshot time the mean
NEES (3 dof) of every station whose covariance is full rank, its horizontal (2 dof) and vertical (1 dof)
parts, the mean absolute height error against the mean height sigma, and the same NEES once the rigid
motion of the whole field against the truth is removed (weighted by the covariances,
``stations.core.rigid_motion``): what is left is the error relative to the field's own datum.

    scripts/datum_nees.py seed000 --trials 8 --duration 300 --sigma-d 0.5 --founders-leave
    scripts/datum_nees.py seed001 --trials 10 --duration 90
    scripts/datum_nees.py --world7
    scripts/datum_nees.py --world7 --fleet-timing

``--world7``: the 7-station world of tests/larns/test_fleet_faults.py (world seed 1), station 1 silent
from 15 s and back at 30 s, station 5 leaving at 25 s (``--fleet-timing``: the fleet test's own times,
killed at 30 s and back at 45 s, leaving at 40 s); prints every station's 3-D error and sigma at 30,
45, 59 and 90 s (30, 45, 60, 75 s) (``tests/stations/test_datum.py::test_seven_station_world_survivors_within_4_sigma``
checks 59 s). Run with PYTHONPATH set to the checkout whose code is to be measured.
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def world7(fleet_timing: bool) -> None:
    """The 7-station world: per station, 3-D error / sigma, height error / sigma, 3-D NEES; the largest
    3-D error in units of 4 sigma + 0.5 m. ``fleet_timing``: the fleet test's own faults (station 1
    killed at 30 s and back at 45 s, station 5 leaving at 40 s; 30, 45, 60, 75 s)."""
    from net.scenario import from_dict
    from stations.sim import Simulator

    sys.path.insert(0, str(ROOT / "tests"))
    from scenario_text import random_world

    text = random_world("faults", 7).replace("ranges_per_update = 3\n", 'ranges_per_update = 3\ndatum = "field"\n')
    if fleet_timing:
        times, stop, restart = [30.0, 45.0, 60.0, 75.0], {1: 30.0, 5: 40.0}, {1: 45.0}
    else:
        times, stop, restart = [30.0, 45.0, 59.0, 90.0], {1: 15.0, 5: 25.0}, {1: 30.0}
    sim = Simulator(from_dict(tomllib.loads(text)), stop_s=stop, restart_s=restart)
    worst = 0.0
    r = sim.run(max(times), times)
    for k, t in enumerate(times):
        print(f"t = {t:.0f} s   (station: 3-D error / 3-D sigma m, height error / sigma m, NEES 3 dof; * outside 4 sigma + 0.5 m)")
        for i, sid in enumerate(r.ids):
            e, P = r.pos_m[k, i] - r.truth_m[i], r.cov_m2[k, i]
            if not np.isfinite(e[0]):
                print(f"  {sid}: gone")
                continue
            s3 = float(np.sqrt(np.trace(P)))
            q = float(e @ np.linalg.solve(P, e)) if np.all(np.diag(P) > 0) else float("nan")
            worst = max(worst, float(np.linalg.norm(e)) / (4.0 * s3 + 0.5))
            flag = "*" if np.linalg.norm(e) >= 4.0 * s3 + 0.5 else ""
            print(f"  {sid}: {np.linalg.norm(e):6.2f} / {s3:5.2f}   {e[2]:+6.2f} / {np.sqrt(P[2, 2]):5.2f}   {q:8.2f} {flag}")
    print("datum mode:", sorted(c.id for c in sim.cores if c is not None and c.est.datum_sigma_m is not None))
    print(f"largest 3-D error / (4 sigma + 0.5 m): {worst:.2f}")


def _nees(e: np.ndarray, P: np.ndarray) -> tuple[float, float, float]:
    """3-D, horizontal and vertical NEES of one error (3,) against its covariance (3, 3)."""
    return (float(e @ np.linalg.solve(P, e)), float(e[:2] @ np.linalg.solve(P[:2, :2], e[:2])),
            float(e[2] ** 2 / P[2, 2]))


def trial(scenario: str, seed: int, sigma_d: float | None, duration: float, times: list[float],
          leave: bool) -> np.ndarray:
    """One trial: (T, n, 6) per snapshot and station: NEES 3/h/z, NEES 3 with the rigid motion removed,
    |height error|, height sigma (NaN where the covariance is not full rank)."""
    from net.scenario import load
    from stations.core import rigid_motion
    from stations.sim import Simulator

    scn = load(scenario, seed=seed, survey={"datum": "field"},
               **({"channel": {"sigma_d_m": sigma_d}} if sigma_d else {}))
    stop = {1: 60.0, 2: 120.0, 3: 180.0} if leave else None
    r = Simulator(scn, estimator="dmap", stop_s=stop).run(duration, times)
    out = np.full((len(times), len(r.ids), 6), np.nan)
    for k in range(len(times)):
        e, P = r.pos_m[k] - r.truth_m, r.cov_m2[k]
        ok = np.isfinite(e[:, 0]) & np.all(np.diagonal(P, axis1=1, axis2=2) > 0.0, axis=1)
        er = e
        if ok.sum() >= 4:
            t_m, w_rad = rigid_motion(r.pos_m[k, ok], P[ok], r.truth_m[ok])
            er = e - t_m - np.cross(w_rad, r.truth_m)
        for i in np.flatnonzero(ok):
            out[k, i, :3] = _nees(e[i], P[i])
            out[k, i, 3] = _nees(er[i], P[i])[0] if ok.sum() >= 4 else np.nan
            out[k, i, 4], out[k, i, 5] = abs(e[i, 2]), np.sqrt(P[i, 2, 2])
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("scenario", nargs="?", default="seed000")
    p.add_argument("--trials", type=int, default=8)
    p.add_argument("--duration", type=float, default=300.0)
    p.add_argument("--sigma-d", type=float, default=None, help="range sigma, m (default: the scenario's)")
    p.add_argument("--seed", type=int, default=1, help="trial k uses seed + k")
    p.add_argument("--founders-leave", action="store_true", help="stations 1, 2, 3 silent at 60, 120, 180 s")
    p.add_argument("--world7", action="store_true", help="the 7-station world of the fleet-faults test")
    p.add_argument("--fleet-timing", action="store_true", help="--world7 with the fleet test's own fault times")
    a = p.parse_args()
    if a.world7:
        world7(a.fleet_timing)
        return 0
    from scipy.stats import chi2

    times = [t for t in (30.0, 60.0, 90.0, 120.0, 180.0, 240.0, 300.0) if t <= a.duration]
    t0 = time.perf_counter()
    res = np.stack([trial(a.scenario, a.seed + k, a.sigma_d, a.duration, times, a.founders_leave)
                    for k in range(a.trials)])  # (trials, T, n, 6)
    with np.errstate(invalid="ignore"):
        import warnings

        warnings.simplefilter("ignore", RuntimeWarning)
        per_station = np.nanmean(res[..., 0], axis=0)  # (T, n)
        print(f"{a.scenario}, datum = field{', founders leave' if a.founders_leave else ''}, {a.trials} trials, "
              f"{time.perf_counter() - t0:.0f} s")
        print("t_s  NEES3  NEES_h(2)  NEES_z(1)  NEES3_rigid_removed  |ez|_m  sigma_z_m  max_station_NEES3")
        for k, t in enumerate(times):
            m = [np.nanmean(res[:, k, :, j]) for j in range(6)]
            print(f"{t:4.0f} {m[0]:6.2f} {m[1]:9.2f} {m[2]:10.2f} {m[3]:20.2f} {m[4]:7.2f} {m[5]:10.2f} "
                  f"{np.nanmax(per_station[k]):18.2f}")
    lo, hi = chi2.ppf([0.025, 0.975], 3 * a.trials) / a.trials
    print(f"95% band of one station's mean NEES over {a.trials} trials (3 dof): [{lo:.2f}, {hi:.2f}]")
    return 0


if __name__ == "__main__":
    sys.exit(main())
