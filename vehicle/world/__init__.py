"""Vehicle world: truth motion along the route, IMU, odometer, receiver clock, radio. Truth lives here."""
