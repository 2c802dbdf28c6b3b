"""Pure computation on numpy arrays: calibration, epipolar geometry, matching, triangulation,
illumination, features, association, weight. No I/O here except the survey entry and the
calibration file codec in ``calib_file``."""
