"""The C firmware (firmware_sim/c) from Python: its per-robot servo table, its builds, and the
launcher that runs it with the servo-bus plant (``python -m firmware_sim --firmware c|qemu``)."""
