"""rendering stage of the core."""
