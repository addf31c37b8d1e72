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

from net.blas import one_thread

one_thread()  # first: before NumPy loads

__version__ = "0.1.0"
