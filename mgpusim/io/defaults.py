"""Defaults of the outputs that the command line names in its help, apart from the modules that
write them (those load pandas and matplotlib; `mgpusim --help` should not)."""

#: The last frames a run's Perfetto trace holds by default (the whole trace is in trace.parquet).
TRACE_FRAMES = 300
#: At most this many task slices in the default Perfetto window: fewer frames than
#: TRACE_FRAMES where a frame has thousands of tasks (a many-chunk pipeline), so the file
#: still opens at once in the UI.
PERFETTO_SLICES = 100_000
#: Rows the trace table holds by default: the whole run up to this many rows, else its first
#: frames that fit (a 10^6-frame run of a ten-task frame still fits).
TRACE_ROWS = 10_000_000
