"""How fast the model is and what accuracy costs: model speed (:mod:`.model_speed`) against
its references, raw SimPy and a hand-written SimPy model of one frame (:mod:`.reference`), and
each fidelity level's time and error on measured runs (:mod:`.accuracy_cost`), for `mgpusim
bench` and `mgpusim fidelity`."""
