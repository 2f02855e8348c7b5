"""Measuring the thesis's own renderer, vmgpu (with its library bp), on lavapipe: a sphere mesh of
a chosen triangle count, a grid of strategy x simulated GPUs x triangles x resolution run under
Xvfb with repeats interleaved, each run's per-frame times parsed from vmgpu's frame log, and the
runs written once at the end as Parquet tables with their provenance.

Why: the model's lavapipe predictions were checked against the project's own Vulkan backend;
vmgpu is the system the thesis measured, so its frame times are an independent target. The tool
takes an already-built vmgpu build folder and never builds it.
"""
