"""Shared test support: ``tests/`` on ``sys.path`` so the test folders (which mirror the packages:
nav/, net/, stations/, aircraft/, vehicle/, larns/) can import the helpers here (``scenario_text``)."""

import os
import sys
from pathlib import Path

# the vehicle's single-run kernel runs as NumPy code in the suite (and in the processes it starts):
# numba's first compilation on a fresh machine takes ~13 s; tests/vehicle/test_vehicle_filter_fast.py
# checks the compiled kernel against it in a process of its own (slow)
os.environ.setdefault("LARNS_JIT", "off")
# BLAS on one thread as in every LARNS process (net/blas.py): the suite re-flies recorded estimates
# in-process and compares them bit for bit, and a threaded OpenBLAS rounds some products differently
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # net.blas.one_thread, before the paths below exist

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)
# the repository root too: ``tests/larns`` (no __init__) on the path would otherwise be found as a
# namespace package ``larns`` before the editable install's finder (a meta-path finder placed after
# the path finder by recent setuptools) when a test imports ``larns`` first
_ROOT = str(Path(__file__).resolve().parents[1])
if _ROOT not in sys.path:
    sys.path.append(_ROOT)


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
    then the compose tests, which build their image and run their timeline (~100 s) on their own. (The
    build used to overlap the first phase and the timeline the second: on a slower 2-core machine the
    build made the timed process tests fail and the in-process tests starved the containers.)"""
    items.sort(key=_phase)


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
