"""CoCo on the host: interface binding and the runtime that moves the robot over the link."""
