"""Stage 3 — the factor graph: building a ``Problem`` from a dataset, the projection factors,
robust initialisation, Levenberg-Marquardt with marginal covariances, iSAM2 for live updates,
observability checks, workspace uncertainty maps and the ``Result`` type.

Its rooms, each a subpackage, from the ground floor up (a room imports only rooms below it)::

    output       the Result and its file form
    terms        keys, views, factors, initial guesses, the corner-noise model, linearised graphs
    robot        the robot's error model: FK check, joint offsets, their selection
    fit          the graph, its start, its robust rounds
    camera       the intrinsics model, claims, the intrinsics session and its plan
    uncertainty  covariances, error budget, prediction, observability, the workspace
    changes      a camera that moved during capture or since calibration
    solve        solve() itself, the Problem from a dataset, the incremental solver
"""
