"""Stage 2 — finding the target's points in an image: checkerboard, ChArUco and circle-grid
detection with up-scaling for far cameras, and the grid filter that rejects false detections."""
