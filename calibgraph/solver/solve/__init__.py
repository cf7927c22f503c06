"""The solve itself, the solver's top floor: ``solve(problem) -> Result`` (``batch``) as one
straight line through the rooms below (views, start, ``optimise``, ``camera_model``, ``assemble``),
the Problem built from a dataset folder (``build``) and the incremental iSAM2 solver
(``incremental``)."""
