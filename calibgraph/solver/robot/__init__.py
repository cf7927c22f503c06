"""The robot's error model: its forward kinematics judged against its stated accuracy
(``fk_check``), which FK error component to widen (``fk_select``), joint zero offsets estimated in
the graph (``kinematics``) and the robot error model chosen by held-out captures
(``kinematics_select``). The corner noise it is told apart from is :mod:`calibgraph.solver.terms.noise_model`."""
