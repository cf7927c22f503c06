"""The terms of the calibration graph: its keys, the views (a camera's corners in one capture),
the view and corner factors (``factors``, ``factors_ppp``), the planar-safe initial guesses, the
corner-noise model (``noise_model``), and a solved graph linearised and reduced to its few global
variables (``linearise``, ``reduced``). Imports only :mod:`calibgraph.solver.output`."""
