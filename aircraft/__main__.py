"""`python -m aircraft --scenario S --algo ukf-pr ...`: one aircraft process (same as `larns aircraft`)."""

from net.blas import one_thread

one_thread()  # first: before NumPy loads

from net.cli import exit_process

from .node import main

exit_process(main())
