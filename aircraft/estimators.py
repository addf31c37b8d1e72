"""Aircraft position estimators: the names of :mod:`aircraft.navigator.radio`, where they live.

* :func:`lsq_pr`, :func:`lsq_tdoa`, :func:`lsq_cov` - snapshot least squares (``radio/lsq.py``);
* :class:`Tuning` (``radio/tuning.py``), :class:`CvTracker` - EKF or UKF on the constant-velocity model,
  pseudorange or TDOA measurements (``radio/tracker.py`` composing the parts of ``radio/``);
* :class:`AircraftEstimator`, :class:`EstimatorConfig` - the message-level API (``radio/estimator.py``).
"""

from __future__ import annotations

from .navigator.radio.estimator import ALGOS, AircraftEstimator, EstimatorConfig
from .navigator.radio.lsq import lsq_cov, lsq_pr, lsq_tdoa, mirror_above
from .navigator.radio.snapshot import TrackerSnapshot
from .navigator.radio.tracker import CvTracker
from .navigator.radio.tuning import CLOCK_BIAS_TAU_S, Tuning

__all__ = ["ALGOS", "CLOCK_BIAS_TAU_S", "AircraftEstimator", "CvTracker", "EstimatorConfig", "Tuning",
           "TrackerSnapshot", "lsq_cov", "lsq_pr", "lsq_tdoa", "mirror_above"]
