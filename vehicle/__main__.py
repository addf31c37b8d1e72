"""`python -m vehicle --scenario S [--route FILE]`: one vehicle process (same as `larns vehicle`)."""

from net.blas import one_thread

one_thread()  # first: before NumPy loads

from net.cli import exit_process

from .node import main

exit_process(main())
