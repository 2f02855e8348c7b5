"""The advisor: given one frame's passes, which multi-GPU schedule, how many GPUs and which link.

:mod:`.advisor` searches the options on the model and ranks them; :mod:`.report` writes the
advice (tables, timelines, HTML); :mod:`.on_hardware` measures the advised options for real and
checks the ranking. It needs nothing above the model, the simulator and the writers.
"""
