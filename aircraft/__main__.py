"""`python -m aircraft --scenario S --algo ukf-pr ...`: one aircraft process (same as `larns aircraft`)."""

import sys

from .node import main

sys.exit(main())
