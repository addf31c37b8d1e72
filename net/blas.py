"""BLAS on one thread in every LARNS process: :func:`one_thread`, called by each entry point (``larns``,
``python -m stations`` / ``aircraft`` / ``vehicle``) before NumPy loads; no effect once it has.

A fleet is many processes sharing the cores, so a process gains nothing from BLAS worker threads, and
OpenBLAS's workers spin for work beside the others. The thread count is also part of exact replay (a
threaded OpenBLAS rounds some products differently). An ``OPENBLAS_NUM_THREADS`` already in the
environment is kept (docs/fleet.md, "BLAS on one thread")."""

import os


def one_thread() -> None:
    """Ask OpenBLAS for one thread unless the environment already chose (before NumPy loads)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
