"""Fitting the graph: the factor graph of a calibration with one LM run and its marginals
(``graph``), the initial values of every camera pose and the board mount (``start``), the robust
rounds (re-weighting, view rejection: ``robust``) and the wall time per stage (``timing``)."""
