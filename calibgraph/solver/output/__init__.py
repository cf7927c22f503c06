"""What the solver hands back: the :class:`~calibgraph.solver.output.result.Result` (cameras, pairs,
board mount, robot section, notes) and its file form, ``Result.save`` / ``load_result``, which
round-trip every number (``result_values``: the checked values of a result file).
The ground floor of the solver: it imports no other room."""
