"""Shared test support: ``tests/`` on ``sys.path`` so the test folders (which mirror the packages:
nav/, net/, stations/, aircraft/, vehicle/, larns/) can import the helpers here (``scenario_text``)."""

import os
import sys
from pathlib import Path

# the vehicle's single-run kernel runs as NumPy code in the suite (and in the processes it starts):
# numba's first compilation on a fresh machine takes ~13 s; tests/vehicle/test_vehicle_filter_fast.py
# checks the compiled kernel against it in a process of its own (slow)
os.environ.setdefault("LARNS_JIT", "off")

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)


def _compose_module(item):
    mod = getattr(item, "module", None)
    return mod if getattr(mod, "start_image_build", None) is not None else None


def _phase(item) -> int:
    """0: tests that start processes (marker e2e), 1: in-process tests, 2: the compose tests."""
    if _compose_module(item) is not None:
        return 2
    return 0 if item.get_closest_marker("e2e") is not None else 1


def pytest_collection_modifyitems(session, config, items):
    """Order (stable within each phase): the tests that start processes, then the in-process tests,
    then the compose tests. The compose image build and then the compose timeline (~70 s of Docker
    containers, mostly sleeping on this side) run in the background during the second phase
    (pytest_runtest_setup), where no test of ours needs the machine's timing, and the compose tests
    at the end read its result. (The build used to overlap the first phase: on a slower 2-core
    machine its pip install made the timed process tests fail.)"""
    items.sort(key=_phase)


_COMPOSE: dict = {}


def pytest_collection_finish(session):
    """Remember the compose module of a session that has compose tests (nothing starts yet)."""
    for item in session.items:
        mod = _compose_module(item)
        if mod is not None:
            _COMPOSE["module"] = mod
            return


def pytest_runtest_setup(item):
    """At the first in-process test, start the image build and then the compose timeline in the
    background (tests/larns/test_compose.py: start_compose_timeline; see above)."""
    mod = _COMPOSE.get("module")
    if mod is not None and "started" not in _COMPOSE and _phase(item) >= 1:
        _COMPOSE["started"] = True
        mod.start_compose_timeline()


# ----------------------------------------------------------------------------- one recorded fleet
# tests/aircraft/test_aircraft_e2e.py, tests/larns/test_replay.py and tests/vehicle/test_vehicle_e2e.py
# read the same run: 5 station processes + the aircraft (three filters) + the vehicle + the fleet's
# recorder over real Zenoh on loopback, and a second recorder (our own process) SIGKILLed about 3/4
# into the run (its file has no summary/footer and ends wherever the kill hit). One run instead of
# three saves ~30 s of the default suite.

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def fleet_run(tmp_path_factory):
    """The shared recorded fleet (see above): a :class:`fleet_recording.FleetRecording`."""
    from fleet_recording import record_fleet

    return record_fleet(tmp_path_factory.mktemp("fleet_run"))
