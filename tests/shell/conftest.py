"""Shell tests run on Trio's virtual clock through AnyIO: fake functions that
``await anyio.sleep(d)`` take exactly ``d`` virtual seconds."""

from __future__ import annotations

import pytest
from trio.testing import MockClock


@pytest.fixture
def anyio_backend():
    return ("trio", {"clock": MockClock(autojump_threshold=0)})


@pytest.fixture
def coco():
    """Factory: ``coco(**shell_kwargs) -> (Shell, SimulatedQuadruped)`` with the example CoCo-like modules."""
    from host.testing.quadruped import SimulatedQuadruped, modules
    from host.shell.registry import Registry
    from host.shell.shell import Shell

    def make(reset_seconds: float = 0.0, **kw):
        impl = SimulatedQuadruped(reset_seconds=reset_seconds)
        return Shell(Registry(modules(impl)), **kw), impl

    return make
