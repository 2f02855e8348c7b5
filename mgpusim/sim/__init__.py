"""The event model: the SimPy engine, the fluid channels and executors, the effects a scene needs,
the exact fast-forward and the analytic level; `simulation.simulate` runs an experiment on it."""
