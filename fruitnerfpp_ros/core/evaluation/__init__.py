"""evaluation stage of the core."""
