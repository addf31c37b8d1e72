"""Scenario TOML texts shared by the tests that launch real processes (e2e, compose, replay, aircraft)."""

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
