"""Stage 5 — moving the robot and capturing: the device interfaces drivers implement, the
acquisition state machine with its journal (resume after a crash), and the safety checks."""
