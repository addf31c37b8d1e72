"""The local fleet launcher behind ``larns fleet``: :mod:`~larns.fleet.plan` (which processes, which
arguments, one shared epoch), :mod:`~larns.fleet.spawn`, :mod:`~larns.fleet.watch` (late joiners,
live table from :mod:`~larns.fleet.monitor`), :mod:`~larns.fleet.stop`; :mod:`~larns.fleet.run`
puts them together. The command's arguments: ``larns/commands/fleet.py``.
"""


def __getattr__(name):  # old ``larns.fleet`` names (one release): run_fleet, Monitor, format_table, ...
    import importlib

    for mod in ("run", "monitor", "plan"):
        m = importlib.import_module(f"{__name__}.{mod}")
        if hasattr(m, name):
            return getattr(m, name)
    if name == "mcap_station_summary":
        from larns.analysis.summary import mcap_station_summary

        return mcap_station_summary
    raise AttributeError(name)
