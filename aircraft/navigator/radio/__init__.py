"""The radio aircraft's filters, written as parts that compose (docs/aircraft.md, "Estimators").

* :mod:`.state` - the state layout with named blocks; :mod:`.snapshot` - a filter's saved state;
* :mod:`.tuning` - the filters' tuning; :mod:`.lsq` - the snapshot least squares;
* :mod:`.measurements` - pseudorange and range-difference models (value, Jacobian, noise) and the
  ranges' second-order terms;
* :mod:`.chart` - the inverse-range coordinates; :mod:`.floor` - the height floor constraint;
* :mod:`.lag` - the lagged-Jacobian rule; :mod:`.repeats` - the repeat count of the linearization
  error; :mod:`.biases` - the stations' clock-bias states;
* :mod:`.update` - the EKF / iterated / UKF update strategies; :mod:`.tracker` - :class:`CvTracker`,
  composing them; :mod:`.estimator` - :class:`AircraftEstimator`, the message-level API.

Nothing here imports :mod:`aircraft.world`.
"""
