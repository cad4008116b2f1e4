"""SocketCAN ``vcan`` interfaces for a command, on any Linux kernel (``ghostshell vcan``).

Where this kernel has the interfaces, or can create them (root, the ``vcan`` module), the command
runs here (:mod:`host.tools.vcan.native`). Elsewhere it runs inside a throwaway User-Mode Linux guest
whose root is this machine's root, so every path and the venv are the same inside
(:mod:`host.tools.vcan.uml`; PID 1 is :mod:`host.tools.vcan.uml_init`).
"""
