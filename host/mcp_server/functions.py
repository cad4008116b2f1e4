"""The robot's functions as MCP tools, one each: how one shell mounts another robot's shell.

``ghostshell mcp --robot arm`` lists, besides ``run_program``/``interrupt``/``state``/``capture``,
a tool per function of the robot's visible vocabulary (``pose``, ``joint_move``, ``wave``, ...)
with the stub's parameters, types, bounds and docstring, and ``say`` for speech. A call runs
``<NAME k="v" .../>`` (or the text, for ``say``) as one turn on the served robot and returns the
turn's outcome, timeline and observations, exactly like ``run_program``. So another shell that
mounts this server (``--mount-mcp arm="ghostshell mcp --robot arm --lockstep"``) writes
``<arm.wave/>`` and its call has the mounted robot's lifecycle: an interrupt there cancels the MCP
request, which cancels the turn here.

The tool's input schema comes from the stub's annotations through the SDK's own pydantic path
(``Literal`` -> enum, ``annotated_types`` bounds -> minimum/maximum); metadata pydantic does not know
(e.g. a UTF-8 byte bound) is dropped from the schema and still checked by this shell's mapper.
"""

from __future__ import annotations

import inspect
from collections.abc import Awaitable, Callable, Iterable
from typing import Annotated, Any
from xml.sax.saxutils import quoteattr

from host.shell.types import FunctionSpec

__all__ = ["element", "function_tools"]

#: tool names the server itself defines (a robot function of the same name is not exposed again)
RESERVED = frozenset({"run_program", "interrupt", "state", "capture", "say"})


def element(name: str, args: dict[str, Any]) -> str:
    """``<name k="v" .../>`` with every value quoted and escaped as a function token."""
    attrs = "".join(f" {k}={quoteattr(_text(v))}" for k, v in args.items() if v is not None)
    return f"<{name}{attrs}/>"


def _text(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)


def _schema_safe(annotation: Any) -> Any:
    """``annotation`` with the ``Annotated`` metadata pydantic understands (annotated_types) kept."""
    import typing

    if typing.get_origin(annotation) is Annotated:
        base, *meta = typing.get_args(annotation)
        known = [m for m in meta if type(m).__module__.startswith("annotated_types")]
        return Annotated[(base, *known)] if known else base  # type: ignore[return-value]
    return annotation


def function_tools(specs: Iterable[FunctionSpec],
                   run: Callable[[str], Awaitable[dict[str, Any]]]) -> list[tuple[str, str, Callable[..., Any]]]:
    """``(tool name, description, async fn)`` for each robot function in ``specs`` (speech as ``say``);
    ``run(program)`` runs one function-token program as a turn and returns its report."""
    out: list[tuple[str, str, Callable[..., Any]]] = []
    for spec in specs:
        if spec.speech:
            async def say(text: str) -> dict[str, Any]:
                return await run(text)

            out.append(("say", "Say `text` aloud on the robot (its speaker).", say))
            continue
        if spec.name in RESERVED:
            continue
        out.append((spec.name, (spec.doc or spec.name).strip(), _tool(spec, run)))
    return out


def _tool(spec: FunctionSpec, run: Callable[[str], Awaitable[dict[str, Any]]]) -> Callable[..., Any]:
    name = spec.name

    async def call(**kwargs: Any) -> dict[str, Any]:
        return await run(element(name, kwargs))

    params = [inspect.Parameter(p.name, inspect.Parameter.KEYWORD_ONLY, annotation=_schema_safe(p.annotation),
                                default=p.default) for p in spec.params]
    call.__signature__ = inspect.Signature(params, return_annotation=dict[str, Any])  # type: ignore[attr-defined]
    call.__annotations__ = {p.name: p.annotation for p in params} | {"return": dict[str, Any]}
    call.__name__ = name
    return call
