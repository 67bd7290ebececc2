"""fields stage of the core."""
