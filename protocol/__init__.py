"""The GhostShell wire protocol: messages (:mod:`protocol.messages`), payload codec
(:mod:`protocol.codec`), serial framing (:mod:`protocol.framing`) and frame-log
records (:mod:`protocol.framelog`). Pure code: no I/O, threads or clocks."""
