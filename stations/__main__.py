"""`python -m stations --id N --scenario S ...`: one station process (same as `larns station`)."""

import sys

from .node import main

sys.exit(main())
