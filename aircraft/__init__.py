"""Aircraft: trajectories, clocks, IMU, positioning estimators, process entry."""
