"""The aircraft's navigator side: estimators that see measurements, broadcasts and their own IMU
samples only. Nothing here may import :mod:`aircraft.world` (tests/aircraft/test_ins.py checks it)."""
