"""The aircraft's world side: truth lives here only (6-DOF motion, IMU, receiver clock, the field's
physical frame). Navigator modules (:mod:`aircraft.navigator`) never import this package."""
