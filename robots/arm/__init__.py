"""The desk arm, a 6-servo arm of the SO-101 class: its package (``robot.toml`` and the files it names).

Generic code reads it through :func:`robots.registry.load_robot` (``"arm"``); its Python modules
are :mod:`robots.arm.kinematics` (forward/inverse kinematics), :mod:`robots.arm.behaviours` (the
motion generators) and :mod:`robots.arm.interface` (the stubs the LLM sees).
"""
