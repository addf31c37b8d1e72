"""The package dependency direction of docs/architecture.md, checked on the import graph of the code.

The graph is generated from the source (``ast`` over every module of nav, net, stations, aircraft,
vehicle and larns: ``import`` and ``from ... import`` statements anywhere in a module, including
function-local and relative ones), so a new import against the direction fails here.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("nav", "net", "stations", "aircraft", "vehicle", "larns")
# package -> the packages of ours it may import (docs/architecture.md, "Packages and dependency direction")
ALLOWED = {
    "nav": set(),
    "net": {"nav"},
    "stations": {"nav", "net"},
    "aircraft": {"nav", "net"},
    "vehicle": {"nav", "net"},
    "larns": {"nav", "net", "stations", "aircraft", "vehicle"},
}


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports_in(src: str, pkg: tuple[str, ...]) -> list[tuple[int, str]]:
    """(line, absolute module name) of every import in source ``src`` of a module in package path
    ``pkg`` (e.g. ``("stations",)``); relative imports are resolved against ``pkg``."""
    out = []
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(pkg[: len(pkg) - (node.level - 1)])
                if node.module:
                    out.append((node.lineno, f"{base}.{node.module}" if base else node.module))
                else:  # "from . import x": x is a module of that package
                    out += [(node.lineno, f"{base}.{a.name}" if base else a.name) for a in node.names]
            else:
                out.append((node.lineno, node.module or ""))
    return out


def import_graph() -> dict[str, list[tuple[str, int, str]]]:
    """{module: [(file, line, imported module of ours)]} over every module of our packages."""
    graph: dict[str, list[tuple[str, int, str]]] = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            graph[_module_name(f)] = [(str(f.relative_to(ROOT)), line, name)
                                      for line, name in imports_in(f.read_text(), f.relative_to(ROOT).parent.parts)
                                      if name.split(".")[0] in PACKAGES]
    return graph


GRAPH = import_graph()


def test_the_graph_covers_every_package():
    assert {m.split(".")[0] for m in GRAPH} == set(PACKAGES)
    assert len(GRAPH) > 50
    # the relative-import resolution works: stations/node.py imports stations.shellfaults relatively
    assert any(name == "stations.shellfaults" for _f, _l, name in GRAPH["stations.node"])


@pytest.mark.parametrize("pkg", PACKAGES)
def test_package_dependency_direction(pkg):
    bad = [f"{f}:{line} imports {name}" for mod, edges in GRAPH.items() if mod.split(".")[0] == pkg
           for f, line, name in edges
           if name.split(".")[0] not in ALLOWED[pkg] | {pkg}]
    assert not bad, f"{pkg} may depend on {sorted(ALLOWED[pkg]) or 'nothing of ours'} only:\n" + "\n".join(bad)


# what a navigator may never reach: the truth (``world/``) and, in the aircraft, the Monte Carlo drivers
# that draw worlds and run navigators in batch (``montecarlo/``: they import the world)
OUTSIDE_NAVIGATOR = {"aircraft": ("aircraft.world", "aircraft.montecarlo"), "vehicle": ("vehicle.world",)}


@pytest.mark.parametrize("pkg", ["aircraft", "vehicle"])
def test_navigator_never_imports_the_world(pkg):
    """Truth never reaches an estimator: ``navigator/`` does not import ``world/`` (nor ``montecarlo/``)."""
    assert any(m.startswith(f"{pkg}.navigator.") for m in GRAPH)
    assert all(any(m.startswith(out) for m in GRAPH) for out in OUTSIDE_NAVIGATOR[pkg])
    bad = [f"{f}:{line} imports {name}" for mod, edges in GRAPH.items() if mod.startswith(f"{pkg}.navigator")
           for f, line, name in edges if name.startswith(OUTSIDE_NAVIGATOR[pkg])]
    assert not bad, "\n".join(bad)


def _owner(name: str, graph) -> str:
    """The module of ``graph`` that an imported name refers to (``pkg.mod.symbol`` -> ``pkg.mod``)."""
    while name and name not in graph:
        name = name.rpartition(".")[0]
    return name


def reaches(start: str, graph) -> dict[str, str]:
    """{module: the module that first imported it} over the transitive import closure of ``start``."""
    via: dict[str, str] = {}
    stack = [start]
    while stack:
        mod = stack.pop()
        for _f, _l, name in graph.get(mod, []):
            target = _owner(name, graph)
            if target and target != start and target not in via:
                via[target] = mod
                stack.append(target)
    return via


def truth_paths(pkg: str, graph, starts: list[str] | None = None) -> list[str]:
    """Every import chain from a module of ``pkg.navigator`` (or of ``starts``) to a module outside the
    navigator's reach (:data:`OUTSIDE_NAVIGATOR`), as ``a -> b -> c``."""
    out = []
    for start in starts or sorted(m for m in graph if m.startswith(f"{pkg}.navigator")):
        via = reaches(start, graph)
        for bad in sorted(m for m in via if m.startswith(OUTSIDE_NAVIGATOR[pkg])):
            chain = [bad]
            while chain[-1] != start:
                chain.append(via[chain[-1]])
            out.append(" -> ".join(reversed(chain)))
    return out


@pytest.mark.parametrize("pkg", ["aircraft", "vehicle"])
def test_navigator_never_reaches_the_world_transitively(pkg):
    """Not through any chain of imports either: a navigator module that imports a flat module that
    imports ``world/`` (or ``montecarlo/``) fails here."""
    assert not truth_paths(pkg, GRAPH), "\n".join(truth_paths(pkg, GRAPH))


# issue 29: the flat estimation modules moved into the radio navigator, the truth trajectory into world/,
# the Monte Carlo drivers into montecarlo/ (no old names left behind)
MOVED = {"aircraft.fde": "aircraft.navigator.radio.fde", "aircraft.raim": "aircraft.navigator.radio.raim",
         "aircraft.initializer": "aircraft.navigator.radio.initializer",
         "aircraft.coords": "aircraft.navigator.radio.coords", "aircraft.models": "aircraft.navigator.radio.models",
         "aircraft.trajectory": "aircraft.world.trajectory", "aircraft.sim": "aircraft.montecarlo.radio",
         "aircraft.ins_sim": "aircraft.montecarlo.ins", "aircraft.triad_sim": "aircraft.montecarlo.triad",
         "aircraft.estimators": None}


@pytest.mark.parametrize("old", sorted(MOVED))
def test_the_split_left_no_old_module(old):
    assert old not in GRAPH
    assert MOVED[old] is None or MOVED[old] in GRAPH


@pytest.mark.parametrize("mod", sorted(m for m in MOVED.values() if m and m.startswith("aircraft.navigator.")))
def test_every_moved_navigator_module_stays_clear_of_world_and_montecarlo(mod):
    """Each module moved into the navigator, on its own: its whole import closure reaches neither
    ``world/`` nor ``montecarlo/`` (the receiver's true clock went to ``world/clock.py``)."""
    assert mod in GRAPH
    assert not truth_paths("aircraft", GRAPH, [mod]), "\n".join(truth_paths("aircraft", GRAPH, [mod]))


def test_a_planted_transitive_violation_is_found():
    """The transitive check can fail: a navigator module importing a helper that imports the world."""
    graph = {k: list(v) for k, v in GRAPH.items()}
    graph["aircraft.navigator.planted"] = [("p.py", 1, "aircraft.navigator.receiver")]
    graph["aircraft.navigator.receiver"] = graph["aircraft.navigator.receiver"] + [("r.py", 2, "aircraft.helper")]
    graph["aircraft.helper"] = [("h.py", 3, "aircraft.world.imu.ImuModel")]
    assert "aircraft.navigator.planted -> aircraft.navigator.receiver -> aircraft.helper -> aircraft.world.imu" \
        in truth_paths("aircraft", graph)
    # and a navigator module that reaches a Monte Carlo driver (through a flat helper) fails as well
    graph["aircraft.navigator.radio.planted"] = [("q.py", 1, "aircraft.helper2.f")]
    graph["aircraft.helper2"] = [("h2.py", 4, "aircraft.montecarlo.radio.run_algo")]
    assert "aircraft.navigator.radio.planted -> aircraft.helper2 -> aircraft.montecarlo.radio" \
        in truth_paths("aircraft", graph)
    assert not truth_paths("aircraft", GRAPH)


def test_the_parser_sees_local_and_relative_imports():
    """A checker that cannot fail is no check: function-local, relative and ``from . import`` imports
    of a module of ``net/`` are all resolved to what the direction test compares."""
    src = "import numpy\ndef f():\n    from stations import core\n    from ..aircraft.node import x\n" \
          "    from . import bus\n    import vehicle.sim as vs\n"
    names = [n for _l, n in imports_in(src, ("net",))]
    assert names == ["numpy", "stations", "aircraft.node", "net.bus", "vehicle.sim"]
    assert [n for n in names if n.split(".")[0] in PACKAGES and n.split(".")[0] not in ALLOWED["net"] | {"net"}] \
        == ["stations", "aircraft.node", "vehicle.sim"]


def test_every_module_imports():
    """Every module of ours imports, and every relative import in it - also inside a function -
    names a module that exists (one left behind by a move fails here, not in a subprocess deep inside
    an end-to-end test)."""
    import importlib
    import importlib.util

    missing = []
    for path in sorted(ROOT.glob("*/**/*.py")):
        rel = path.relative_to(ROOT)
        if rel.parts[0] not in PACKAGES or path.name == "__main__.py":
            continue
        mod = _module_name(path)
        importlib.import_module(mod)
        pkg = mod if path.name == "__init__.py" else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                target = importlib.util.resolve_name("." * node.level + (node.module or ""), pkg)
                if importlib.util.find_spec(target) is None:
                    missing.append(f"{rel}:{node.lineno} {target}")
    assert not missing, missing


def test_the_command_line_starts_without_heavy_imports():
    """``larns --help`` (and every process's start) builds the whole parser: registration must not
    import scipy, matplotlib or zenoh (a recorder that starts seconds late misses the fleet's start)."""
    import subprocess
    import sys

    code = ("import sys, larns.cli as c; c.build_parser(); "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'scipy', 'matplotlib', 'zenoh'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert out.stdout.strip() == "[]", out.stdout


def test_no_function_above_cyclomatic_complexity_25():
    """docs/architecture.md: no function of ours above a cyclomatic complexity of 25 (radon)."""
    radon = pytest.importorskip("radon.complexity", reason="radon is in the test extras")
    over = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            for block in radon.cc_visit(path.read_text()):
                for b in [block, *getattr(block, "closures", []), *getattr(block, "methods", [])]:
                    if b.complexity > 25:
                        over.append(f"{path.relative_to(ROOT)}:{b.lineno} {b.name} {b.complexity}")
    assert not over, over


# --------------------------------------------------------------------------- what the navigator knows
# aircraft/config.py splits the aircraft's configuration into the world's part (true station positions,
# trajectory, receiver clock, channel) and the navigator's (NavigatorConfig). The navigator's part holds
# scalars and names only: a position needs several numbers, so a field that can hold an array, a list,
# a mapping, a tuple of numbers or an arbitrary object is refused, as is a field whose name says truth.
SCALAR_TYPES = (str, int, float, bool, type(None))
TRUTH_WORDS = ("station", "centre", "center", "world", "truth", "trajector", "radio")
# names a configuration or scenario object goes by; the navigator reads no position through them
CONFIG_NAMES = {"ac", "acfg", "aircraft_config", "cfg", "config", "conf", "world", "sc", "scn", "scenario"}
POSITION_ATTRS = {"stations_m", "centre_m", "pos_m", "true_pos"}


def knowledge_leaks(cls, path: str = "", localns: dict | None = None) -> list[str]:
    """Fields of the dataclass ``cls``, recursively through the dataclasses it holds, that could carry a
    true position or the world: a name with a word of :data:`TRUTH_WORDS`, or a type other than a
    scalar, ``X | None`` of one, ``tuple[str, ...]`` or a dataclass (checked in turn). ``localns``: the
    names a class defined in a function annotates with."""
    import dataclasses
    import types
    import typing

    out = []
    hints = typing.get_type_hints(cls, localns=localns)
    for f in dataclasses.fields(cls):
        name, hint = f"{path}{f.name}", hints[f.name]
        if any(w in f.name.lower() for w in TRUTH_WORDS):
            out.append(f"{name}: its name says truth")
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if typing.get_origin(hint) in (typing.Union, types.UnionType) and len(args) == 1:
            hint = args[0]  # X | None
        if dataclasses.is_dataclass(hint):
            out += knowledge_leaks(hint, name + ".", localns)
        elif typing.get_origin(hint) is tuple and typing.get_args(hint) == (str, ...):
            continue
        elif hint not in SCALAR_TYPES:
            out.append(f"{name}: type {hint} can hold a position")
    return out


def position_reads(src: str) -> list[tuple[int, str]]:
    """(line, attribute chain) of every place in ``src`` that reads a position through a configuration or
    scenario object (``ac.stations_m``, ``self.ac.world.centre_m``, ``scn.pos_m``: a name of
    :data:`CONFIG_NAMES` in the chain before a :data:`POSITION_ATTRS` attribute), every ``.centre_m``
    and every ``.world`` (the navigator has none), and every mention of the whole configuration's or
    the world part's type. ``model.stations_m`` (the broadcast estimates a filter holds) passes."""
    out = []
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, ast.Name) and node.id in ("AircraftConfig", "AircraftWorldConfig"):
            out.append((node.lineno, node.id))
        if not isinstance(node, ast.Attribute):
            continue
        chain, base = [node.attr], node.value
        while isinstance(base, ast.Attribute):
            chain.append(base.attr)
            base = base.value
        if isinstance(base, ast.Name):
            chain.append(base.id)
        text = ".".join(reversed(chain))
        if node.attr in ("centre_m", "world") or (node.attr in POSITION_ATTRS and CONFIG_NAMES & set(chain[1:])):
            out.append((node.lineno, text))
    return sorted(out)


def _navigator_sources() -> list[Path]:
    return sorted((ROOT / "aircraft" / "navigator").rglob("*.py"))


def test_the_navigators_configuration_holds_no_truth():
    """NavigatorConfig: scalars and names only, nothing named after the truth; the field bounds are a
    radius and windows (the deployment plan), no station position."""
    from aircraft.config import NavigatorConfig

    assert not knowledge_leaks(NavigatorConfig), knowledge_leaks(NavigatorConfig)


def test_the_loaded_navigator_configuration_carries_no_station_coordinate():
    """Every scenario's loaded navigator part holds scalars only, and is the same for the same field
    turned by 90 degrees about station 1 (same planned area, every station elsewhere): it depends on the
    layout through the deployment area's extent alone. The world part holds the truth."""
    import dataclasses
    from types import SimpleNamespace

    import numpy as np

    from aircraft.config import from_scenario
    from net.scenario import load

    def leaves(obj):
        if dataclasses.is_dataclass(obj):
            for f in dataclasses.fields(obj):
                yield from leaves(getattr(obj, f.name))
        elif isinstance(obj, (tuple, list)):
            for x in obj:
                yield from leaves(x)
        else:
            yield obj

    for path in sorted((ROOT / "net" / "scenarios").glob("*.toml")):
        sc = load(path.stem)
        ac = from_scenario(sc)
        vals = list(leaves(ac.nav))
        assert all(isinstance(v, SCALAR_TYPES) for v in vals), (path.stem, vals)
        p = np.asarray(sc.pos_m, float)
        turned = from_scenario(SimpleNamespace(aircraft=sc.aircraft, channel=sc.channel,
                                               pos_m=np.column_stack([-p[:, 1], p[:, 0], p[:, 2]])))
        assert turned.nav == ac.nav, path.stem
        assert not np.array_equal(turned.world.stations_m, ac.world.stations_m)
        assert np.array_equal(ac.world.stations_m, sc.pos_m)


def test_the_navigator_reads_no_position_of_a_configuration():
    """aircraft/navigator/** never reads ``.stations_m`` / ``.centre_m`` (nor ``.pos_m``) of a
    configuration or scenario, never reaches a ``.world``, never names the whole configuration."""
    assert _navigator_sources()
    bad = [f"{p.relative_to(ROOT)}:{line} {text}" for p in _navigator_sources()
           for line, text in position_reads(p.read_text())]
    assert not bad, "\n".join(bad)


def test_planted_knowledge_leaks_are_found():
    """Both checks can fail: a navigator configuration with station positions, with the world part, with
    a tuple of numbers or a nested leak; navigator code that builds its bounds from the true stations."""
    from dataclasses import dataclass

    import numpy as np

    from aircraft.config import AircraftWorldConfig, NavigatorConfig
    from net.plausible import NavBounds

    @dataclass
    class WithStations:
        algos: tuple[str, ...]
        stations_m: np.ndarray

    @dataclass
    class WithWorld:
        bounds: NavBounds
        world: AircraftWorldConfig | None = None

    @dataclass
    class WithNumbers:
        anchor: tuple[float, ...]

    @dataclass
    class Nested:
        nav: NavigatorConfig
        inner: WithNumbers

    names = dict(locals())
    assert knowledge_leaks(WithStations, localns=names) == ["stations_m: its name says truth",
                                             "stations_m: type <class 'numpy.ndarray'> can hold a position"]
    assert knowledge_leaks(WithWorld, localns=names)[0] == "world: its name says truth"
    assert any("can hold a position" in s for s in knowledge_leaks(WithWorld, localns=names))
    assert knowledge_leaks(WithNumbers, localns=names) == ["anchor: type tuple[float, ...] can hold a position"]
    assert knowledge_leaks(Nested, localns=names) == ["inner.anchor: type tuple[float, ...] can hold a position"]
    leak = ("def bounds_of(ac, clock=None):\n"  # the navigator's bounds from the true stations
            "    return bounds_for(ac.stations_m)\n"
            "def aim(self):\n    return self.ac.world.centre_m\n"
            "def guess(cfg):\n    return cfg.centre_m + scn.pos_m[0]\n"
            "def typed(a: AircraftConfig):\n    return model.stations_m, self.stations_m, est.pos_m\n")
    assert position_reads(leak) == [(2, "ac.stations_m"), (4, "self.ac.world"), (4, "self.ac.world.centre_m"),
                                    (6, "cfg.centre_m"), (6, "scn.pos_m"), (7, "AircraftConfig")]
