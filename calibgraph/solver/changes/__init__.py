"""Did something move? A camera knocked during capture, found and solved as its two poses
(``moved``, ``change_point``), and a camera moved since it was calibrated, tested against the
stored covariance (``verify``)."""
