#!/usr/bin/env bash
# Set up (if needed) and run the main job on lavapipe: measure, calibrate, validate a 2-GPU
# sort-first and sort-last run, and write a report to out/main (or the folder given).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/mgpusim main --held-out --out "${1:-out/main}"
