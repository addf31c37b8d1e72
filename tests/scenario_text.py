"""Scenario TOML texts shared by the tests: those that launch real processes (e2e, compose, replay,
aircraft) and the multi-hop strips of tests/stations/test_multihop*.py (:func:`strip_toml`)."""

from __future__ import annotations

_COMMON = """
[channel]
sigma_d_m = 0.5
turnaround_s = 0.001
[init]
sigma0_m = {sigma0_m}
[survey]
estimator = "dmap"
ranges_per_update = 3
"""


def random_world(name: str, n: int, join_ids=(), cycle_s: float = 0.5, slot_s: float = 0.05,
                 description: str = "", seed: int = 1) -> str:
    """seed000's random 2 x 2 km x 80 m world with test-friendly TDMA timing (slots long enough
    for wall-clock exchanges at --speed 5)."""
    return f"""
name = "{name}"
description = "{description}"
seed = {seed}
[frame]
z_ref = 4
[layout]
kind = "random"
n = {n}
join_ids = {list(join_ids)}
area_m = [2000.0, 2000.0, 80.0]
min_separation_m = 100.0
[tdma]
cycle_s = {cycle_s}
slot_s = {slot_s}
""" + _COMMON.format(sigma0_m=10.0)


def five_stations(name: str, seed: int, extra: str = "") -> str:
    """Five explicit stations over 1.8 x 1.5 km, 50 ms slots in a 0.25 s cycle; ``extra`` appended
    (e.g. an ``[aircraft]`` section)."""
    return f"""
name = "{name}"
seed = {seed}
[frame]
z_ref = 4
[[stations]]
id = 1
pos_m = [0.0, 0.0, 0.0]
[[stations]]
id = 2
pos_m = [1800.0, 0.0, 5.0]
[[stations]]
id = 3
pos_m = [900.0, 1500.0, 0.0]
[[stations]]
id = 4
pos_m = [800.0, 500.0, 60.0]
[[stations]]
id = 5
pos_m = [300.0, 1200.0, 20.0]
[tdma]
cycle_s = 0.25
slot_s = 0.05
""" + _COMMON.format(sigma0_m=5.0) + extra


def aircraft_hover(algos: list[str]) -> str:
    """An ``[aircraft]`` section: hover 1500 m from the centre at 300 m, the given algorithms."""
    return f"""
[aircraft]
name = "ac1"
algos = {list(algos)!r}
sigma_m = 0.5
init_sigma_m = 30.0
[aircraft.trajectory]
kind = "hover"
distance_m = 1500.0
height_m = 300.0
[aircraft.tuning]
q_acc = 1.0
p0 = {{ pos_m = 30.0 }}
""".replace("'", '"')


def strip_toml(name: str, description: str, n: int, depth_m: float, cycle_s: float, tx_power_dbm: float,
               sigma0_m: float, clock: str | None = None) -> str:
    """A multi-hop strip (the far stations hear the founders only through their neighbours): scenario
    text of ``n`` stations at random (500 m apart at least, founders within 2 km) on
    12 km x ``depth_m``, 30 m of ground height, sigma_d 0.5 m, seed 2; ``clock``: a ``[clock] model``."""
    clock_section = "" if clock is None else f'\n[clock]\nmodel = "{clock}"\n'
    return f"""
name = "{name}"
description = "{description}"
seed = 2

[layout]
kind = "random"
n = {n}
area_m = [12000.0, {depth_m!r}, 30.0]
min_separation_m = 500.0
founders_within_m = 2000.0

[tdma]
cycle_s = {cycle_s!r}
slot_s = 0.01

[channel]
sigma_d_m = 0.5

[radio]
tx_power_dbm = {tx_power_dbm!r}
{clock_section}
[init]
sigma0_m = {sigma0_m!r}
"""
