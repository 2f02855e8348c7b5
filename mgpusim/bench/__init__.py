"""How fast the model is and what accuracy costs: model speed against a hand-written SimPy model
(:mod:`.model_speed`) and each fidelity level's time and error on measured runs
(:mod:`.accuracy_cost`), for `mgpusim bench` and `mgpusim fidelity`."""
