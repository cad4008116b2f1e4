"""Fixtures for tests, benchmarks and docs: :mod:`host.testing.quadruped` (an example interface with
fake functions of known duration). Nothing on the runtime path imports from here."""
