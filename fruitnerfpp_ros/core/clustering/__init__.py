"""clustering stage of the core."""
