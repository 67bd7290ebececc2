"""synthetic stage of the core."""
