"""Calibrating a robot's real servo bus (``ghostshell robots calibrate``): the bus through the vendor SDKs
(:mod:`host.calibration.bus`) and the hand-guided procedure that records each servo's offset, direction
and range (:mod:`host.calibration.procedure`). The result is :class:`robots.hardware.Calibration`,
written to the robot package's ``calibration.toml``."""
