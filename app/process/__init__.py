"""The process: a weld run's signature, and runs compared against their parameters (the map)."""
