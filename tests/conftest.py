"""Shared test support: ``tests/`` on ``sys.path`` so the test folders (which mirror the packages:
nav/, net/, stations/, aircraft/, vehicle/, larns/) can import the helpers here (``scenario_text``)."""

import sys
from pathlib import Path

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)


def pytest_collection_finish(session):
    """A session with compose tests starts building their Docker image at once, in the background
    (tests/larns/test_compose.py: start_image_build), so the build overlaps the tests before them."""
    for item in session.items:
        start = getattr(getattr(item, "module", None), "start_image_build", None)
        if start is not None:
            start()
            return
