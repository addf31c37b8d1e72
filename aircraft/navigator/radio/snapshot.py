"""A radio filter's saved state (:meth:`CvTracker.save` / :meth:`CvTracker.restore`): what an update
changes, so that the integrity monitor (aircraft/navigator/radio/fde.py) can re-run an update with other measurements."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class TrackerSnapshot:
    """Everything one update of :class:`~aircraft.navigator.radio.tracker.CvTracker` may change.

    ``x`` (..., n) and ``P`` (..., n, n): the filter's Gaussian in its runs' own coordinates;
    ``inverse`` (...,): runs in inverse-range coordinates, ``ref_m`` (3,) / ``radius_m`` the chart's
    reference point and array radius; ``bias_ids``, ``bias_var_m2``, ``bias_t_s``: the clock-bias
    states; ``t_s``: filter time; ``memory``, ``last_seen``: the repeat count's state; ``lag_pos``,
    ``lag_info``, ``lag_dir``, ``lag_comp``, ``lag_dir_t_s``: the lagged Jacobian's state.
    """

    x: np.ndarray
    P: np.ndarray
    inverse: np.ndarray
    ref_m: np.ndarray | None
    radius_m: float
    bias_ids: tuple
    bias_var_m2: np.ndarray
    bias_t_s: np.ndarray
    t_s: float
    memory: np.ndarray | float
    last_seen: dict
    lag_pos: np.ndarray | None
    lag_info: np.ndarray | None
    lag_dir: np.ndarray | None
    lag_comp: np.ndarray | None
    lag_dir_t_s: float
