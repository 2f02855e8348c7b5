"""Defaults of the outputs that the command line names in its help, apart from the modules that
write them (those load pandas and matplotlib; `mgpusim --help` should not)."""

#: The last frames a run's Perfetto trace holds by default (the whole trace is in trace.parquet).
TRACE_FRAMES = 300
