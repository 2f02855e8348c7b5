#!/usr/bin/env bash
# Set up (if needed) and run the main job on lavapipe: measure, calibrate and validate every
# schedule (experiments/lavapipe/study.toml), and write a report to out/main (or the folder given).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec .venv/bin/mgpusim main --held-out --out "${1:-out/main}"
