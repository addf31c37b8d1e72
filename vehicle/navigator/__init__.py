"""Vehicle navigator: continuous-discrete filters. Never imports vehicle.world."""
