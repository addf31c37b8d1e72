"""`python -m vehicle --scenario S [--route FILE]`: one vehicle process (same as `larns vehicle`)."""

import sys

from .node import main

sys.exit(main())
