"""The servo-bus plant: the world the C firmware drives over its second UART.

One servo model with two wire protocols. Each servo has one protocol-neutral state
(:mod:`firmware_sim.plant.servo`); the Feetech SCS/STS register map
(:mod:`firmware_sim.plant.devices`, packets: :mod:`firmware_sim.plant.feetech`) and the Dynamixel
X-series control table (:mod:`firmware_sim.plant.dxl_table`, Protocol 2.0 packets:
:mod:`firmware_sim.plant.dynamixel`) are views over it. The world (:mod:`firmware_sim.plant.world`)
holds the robot's MuJoCo model and steps it; :mod:`firmware_sim.plant.bus` answers the packets
(:mod:`~firmware_sim.plant.sts_bus`, :mod:`~firmware_sim.plant.dxl_bus`) and models bus time;
:mod:`firmware_sim.plant.conditions` are the injectable hardware conditions;
:mod:`firmware_sim.plant.server` serves it on a pty. The vendors' SDKs (``scservo_sdk``,
``dynamixel_sdk``) talk to it as to real servos. Reference: docs/reference/plant.md.
"""
