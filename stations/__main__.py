"""`python -m stations --id N --scenario S ...`: one station process (same as `larns station`)."""

from net.blas import one_thread

one_thread()  # first: before NumPy loads

from net.cli import exit_process

from .node import main

exit_process(main())
