"""PX4 ULog: the log PX4 writes on the vehicle, one file per arming (docs/vehicle.md).

:mod:`.writer` writes one (the stand-in vehicle's logger, the tests' fixtures); the reader
goes through pyulog.
"""
