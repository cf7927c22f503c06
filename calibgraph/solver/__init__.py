"""Stage 3 — the factor graph: building a ``Problem`` from a dataset, the projection factors,
robust initialisation, Levenberg-Marquardt with marginal covariances, iSAM2 for live updates,
observability checks, workspace uncertainty maps and the ``Result`` type."""
