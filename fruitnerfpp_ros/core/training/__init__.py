"""training stage of the core."""
