"""Stage 5 — moving the robot and capturing: the device interfaces drivers implement and the
registry that opens them, the workcell reader, the one acquisition loop (a fixed trajectory or the
autonomous planner as its plan) with its journal, the dataset claim (what made it, one process at
a time) and the safety checks."""
