"""What the solve's uncertainty means: covariances in the frames a user reads them in
(``covariance``), a camera's error budget (``budget``), the expected error of a new pose
(``prediction``), observability checks that refuse undetermined motions (``observability``) and a
pose covariance in the workspace, in words (``workspace``). The corner-noise model the covariances
are scaled with is :mod:`calibgraph.solver.terms.noise_model`."""
