"""`python -m aircraft --scenario S --algo ukf-pr ...`: one aircraft process (same as `larns aircraft`)."""

# Every LARNS process runs BLAS on one thread (unless the environment says otherwise): the emulator is
# many processes sharing the cores, and OpenBLAS's worker threads spin for work beside them (docs/fleet.md,
# "BLAS on one thread"). Set before NumPy loads; no effect once it has.
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from net.cli import exit_process

from .node import main

exit_process(main())
