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

Modules that moved keep their old import names for one release (``MOVED``): ``import
larns.mcaputil`` gives :mod:`larns.log`, ``larns.info`` gives :mod:`larns.analysis.summary`, ...
"""

import importlib
import importlib.abc
import importlib.util
import sys

__version__ = "0.1.0"

# old module name -> new module (kept for one release; docs/architecture.md)
MOVED = {
    "larns.mcaputil": "larns.log.compat",
    "larns.info": "larns.analysis.summary",
    "larns.report": "larns.viz.report",
    "larns.foxglove": "larns.viz.foxglove",
    "larns.record": "larns.log.record",
    "larns.replay": "larns.commands.replay",
    "larns.recover": "larns.commands.recover",
    "larns.keys": "larns.commands.keys",
    "larns.attack": "larns.commands.attack",
    "larns.progress": "larns.bench.progress",
    "larns.station_cmd": "larns.commands.station",
    "larns.aircraft_cmd": "larns.commands.aircraft",
    "larns.router_cmd": "larns.commands.router",
    "larns.crlb_cmd": "larns.commands.crlb",
    "larns.bench_aircraft": "larns.bench.aircraft",
    "larns.bench_aircraft_envelope": "larns.bench.envelope",
    "larns.bench_survey": "larns.bench.survey",
    "larns.bench_net": "larns.bench.net",
    "larns.bench_sync": "larns.bench.sync",
    "larns.bench_ins": "larns.bench.ins",
    "larns.bench_integrity": "larns.bench.integrity",
    "larns.bench_vehicle": "larns.bench.vehicle",
    "larns.offline": "larns.analysis.offline",
    "larns.bench_replay": "larns.bench.replay",
}


class _Moved(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports an old module name as the module it moved to (the same module object)."""

    def find_spec(self, name, path=None, target=None):
        return importlib.util.spec_from_loader(name, self) if name in MOVED else None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        sys.modules[module.__name__] = importlib.import_module(MOVED[module.__name__])


if not any(isinstance(f, _Moved) for f in sys.meta_path):
    sys.meta_path.append(_Moved())
