"""The sub-commands of `mgpusim`, one module each: arguments, checks before any work, printing."""
