"""Captured frames: the capture formats read (:mod:`.formats`: Chrome trace JSON, CSV, measured
runs, RenderDoc captures replayed by :mod:`.rdc`) and a frame turned into an experiment
(:mod:`.importer`), for `mgpusim frame import`."""
