"""The larns command line and tooling, split by kind:

* :mod:`larns.cli` - the ``larns`` entry point; :mod:`larns.commands` - one thin argparse adapter
  per command;
* :mod:`larns.log` - the recording model (reader, series, timebase, key expressions, writer,
  recorder);
* :mod:`larns.analysis` - numbers from recordings (summaries, metrics);
* :mod:`larns.viz` - figures, the Foxglove view, the Markdown report;
* :mod:`larns.fleet` - the local fleet launcher (plan, spawn, watch, stop);
* :mod:`larns.bench` - one module per benchmark;
* offline re-estimation is :mod:`larns.analysis.offline`; the replay benchmark :mod:`larns.bench.replay`.
"""

# Every LARNS process runs BLAS on one thread (unless the environment says otherwise): the emulator is
# many processes sharing the cores, and OpenBLAS's worker threads spin for work beside them (docs/fleet.md,
# "BLAS on one thread"). Set before NumPy loads; no effect once it has.
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

__version__ = "0.1.0"
