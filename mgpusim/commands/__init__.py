"""The sub-commands of `mgpusim`, one module each: arguments, checks before any work, printing.

Each module imports the model, pandas or matplotlib inside the functions that run its command,
not at the top: `mgpusim --help` builds every command's parser and should load none of them.
"""
