"""Stage 6 — telling people: the HTML commissioning report and its plots, the printable target
PDF, the rerun recording, and exports for robot stacks (URDF, ROS 2 launch, OpenCV YAML)."""
