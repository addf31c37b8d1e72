"""The aircraft's Monte Carlo drivers: they draw worlds (:mod:`aircraft.world`) and run navigators
(:mod:`aircraft.navigator`) on them in batch, vectorized over runs - :mod:`.radio` (the CV radio
filters, seed 001), :mod:`.ins` (the inertial aircraft), :mod:`.triad` (seed 002). They may import
world and navigator; the navigator imports neither world nor this package (tests/test_architecture.py).
"""
