"""Stage 4 — where the robot should go: the board-visibility model, the trajectory type and file
format, and the planner that samples reachable, collision-free poses showing the board to the cameras."""
