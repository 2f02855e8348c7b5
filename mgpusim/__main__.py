"""`python -m mgpusim ...`: the same command line as `mgpusim ...`."""
import sys

from .cli import main

sys.exit(main())
