"""The larns command line and tooling: fleet, recorder, replay, report, benchmarks, scenarios."""
__version__ = "0.1.0"
