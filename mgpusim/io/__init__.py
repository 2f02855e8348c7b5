"""The edges: output paths checked first, run folders written, plots, Perfetto traces, report
pages, and where the shipped experiments and profiles are installed."""
