"""The servo-bus plant: the world the C firmware drives over its second UART.

It answers Feetech SCS/STS packets (:mod:`firmware_sim.plant.feetech`) as the robot's servos, an
IMU and an emulator-only ground-truth probe would (:mod:`firmware_sim.plant.devices`), holds the
robot's MuJoCo model and steps it (:mod:`firmware_sim.plant.world`), and models the bus time at
1 Mbaud (:mod:`firmware_sim.plant.bus`). The vendor SDK (``scservo_sdk``) talks to it as to real
servos.
"""
