"""firmware_sim: a robot's emulated board (control loop, jitter buffer, servo model, safety, peripherals, link server).

Run it with ``python -m firmware_sim --link pty``; the core (:class:`firmware_sim.board.Board`)
works without any I/O for tests.
"""
