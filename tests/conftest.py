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


def pytest_collection_modifyitems(session, config, items):
    """The compose tests run last, so their image build (started at collection, below) overlaps the
    whole suite instead of being waited for half-way."""
    items.sort(key=lambda it: getattr(getattr(it, "module", None), "start_image_build", None) is not None)


def pytest_collection_finish(session):
    """A session with compose tests starts building their Docker image at once, in the background
    (tests/larns/test_compose.py: start_image_build), so the build overlaps the tests before them."""
    for item in session.items:
        start = getattr(getattr(item, "module", None), "start_image_build", None)
        if start is not None:
            start()
            return


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
