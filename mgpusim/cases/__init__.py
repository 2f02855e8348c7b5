"""Case studies: a source system as its authors ran it (a case file under
`experiments/cases/`), its published figures beside the model's predictions, for `mgpusim case`."""
