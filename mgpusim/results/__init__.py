"""Records of a run, simulated or measured: the one trace schema, the per-frame table and summary,
a fast-forwarded run's logs, and the waits from ready to start. Pure functions of data."""
