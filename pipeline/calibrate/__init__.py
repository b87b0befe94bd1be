"""``qsls calibrate``: the premise calibrated on flights the controller flew itself, and the
certificate decided from them (docs/calibration.md)."""
