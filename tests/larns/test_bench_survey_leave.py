"""``larns bench survey --founders-leave`` (docs/survey.md, "The founders leave"): one short trial."""

import numpy as np

from larns.bench.survey import _leave_trial, leave_summary


def test_founders_leave_trial_with_the_scenarios_station_count():
    """Without ``--stations`` (None: the scenario's 10) the trial runs (it used to hand the loader
    ``[layout] n = None``); 61 s: station 1 leaves at 60 s, the survivors are scored against the twin."""
    res = _leave_trial(("seed000", 0.5, None, 1, 61.0, None, None))
    assert res["times"] == [59.0, 61.0]
    assert res["dev_m"].shape == (2, 10)
    assert np.all(res["dev_m"][0] == 0.0)  # before the departure the two runs are one
    assert np.isnan(res["dev_m"][1, 0]) and np.all(np.isfinite(res["dev_m"][1, 1:]))  # station 1 gone
    s = leave_summary([res], 0.5)
    assert s["rows"][-1]["survivors"] == 9
