"""Tooling around the runtime, not on its path: ``vcan`` (SocketCAN inside User-Mode Linux), ``fuzz``
(the coverage-guided fuzz targets and their driver) and ``eval`` (the paper's evaluation: sweeps, the
DSBC metric, the native-call ablation). Nothing under host/shell, host/motion, host/link, host/run
or host/runtime imports from here."""
