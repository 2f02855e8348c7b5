#!/usr/bin/env bash
# Set up (if needed), lint and type-check, then run the test suite. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# ruff and mypy as configured in pyproject.toml; a finding stops here, below their own output
.venv/bin/ruff check mgpusim tests tools benchmarks scripts \
  || { echo "test.sh: ruff found the problems above; tests not run" >&2; exit 1; }
.venv/bin/mypy \
  || { echo "test.sh: mypy found the problems above; tests not run" >&2; exit 1; }
# on every core (pytest-xdist; `-n 0` in the arguments runs them in one process)
exec .venv/bin/python -m pytest -q -n auto "$@"
