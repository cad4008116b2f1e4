"""The local OpenAI-compatible SSE server fixture (``fake_llm``)."""

from support.fake_llm import fake_llm  # noqa: F401  (a fixture, registered by importing it here)
