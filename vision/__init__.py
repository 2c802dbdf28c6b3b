"""Pure computation on numpy arrays: calibration, epipolar geometry, matching, triangulation,
illumination, features, association, weight. No I/O and no import of controller/ or devices/
(import-linter holds this in ``make test``): files are read and written by the command line,
which hands vision decoded data (e.g. CALIB.json's object to ``calib_file.calibration_from_json``)."""
