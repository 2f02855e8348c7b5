"""The vocabulary of the model: errors, bounds, TOML checks, scenes, tasks, work terms, hardware
profiles and the cost model. The bottom layer: it imports nothing else of mgpusim."""
