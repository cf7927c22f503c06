"""The camera model: the intrinsics parameter vector of a distortion model and its information
(``intrinsics_model``), intrinsics declared exact tested against the views (``claims``), and the
close-range intrinsics session of one camera (``intrinsics_session``) with its plan (``session_plan``).
The camera model judged inside a robot solve is :mod:`calibgraph.solver.solve.camera_model`."""
