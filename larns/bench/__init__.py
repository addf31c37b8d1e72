"""Benchmarks, one module per bench (``larns bench NAME``): table + JSON (+ PNG)."""
