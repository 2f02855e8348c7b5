"""The edges: output paths checked first, run folders written, plots, Perfetto traces, a sweep's
resumable folder, and where the shipped experiments and profiles are installed."""
