"""Ground station: TDMA schedule, ranging protocol, self-survey estimators, process entry."""
