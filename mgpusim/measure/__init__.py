"""Measuring on the real backend and judging a measurement: the pass microbenchmarks
(:mod:`.microbench`, :mod:`.overlap`), the machine's speed (:mod:`.speed_probe`,
:mod:`.run_speed`, :mod:`.speed_norm`), the load beside a run (:mod:`.host_load`), repeated runs
and their steady window (:mod:`.repeated_runs`, :mod:`.steady_window`), and the archive of
measured runs on disk (:mod:`.run_archive`)."""
