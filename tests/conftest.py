"""Shared test support: ``tests/`` on ``sys.path`` so the test folders (which mirror the packages:
nav/, net/, stations/, aircraft/, vehicle/, larns/) can import the helpers here (``scenario_text``)."""

import sys
from pathlib import Path

_HERE = str(Path(__file__).resolve().parent)
if _HERE not in sys.path:
    sys.path.insert(0, _HERE)
