"""Fixtures for tests, benchmarks and docs: :mod:`protocol.testing.samples` (one instance of every
message). No codec imports from here."""
