"""Stage 0 — the vocabulary every other stage speaks: rigid transforms (``T_a_b``), camera models
and presets, calibration targets, the observation data model (captures, detections, the
``Problem``), errors and the version. Depends on numpy and OpenCV only."""
