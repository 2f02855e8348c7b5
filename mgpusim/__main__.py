"""`python -m mgpusim ...`: the same command line as `mgpusim ...`."""
import sys

from mgpusim.cli import main

sys.exit(main())
