"""Stack sizes for atheris-instrumented code: the real maximum depth instead of atheris' sum of every push.

atheris 2.x (``instrument_bytecode.Instrumentor.to_code``) sets an instrumented code object's
``co_stacksize`` to the sum of the positive stack effects of all its instructions, an upper bound
that grows with the function's length (the shell parser's ``_scan``: 2 130 slots where the
compiler's own figure for the uninstrumented code is 8). CPython 3.11 reserves ``co_stacksize``
slots for every call on its per-thread data stack, in 16 KiB chunks: a frame larger than a chunk
gets a fresh chunk (``mmap``/``munmap``) on every call, which py-spy showed as 8 % of the shell
target's time on the line calling ``_scan``.

:func:`max_stack_depth` is the compiler's stack-depth pass (CPython ``compile.c`` ``stackdepth``)
over finished bytecode: a walk of every path from the entry and from each exception handler
(entered at the exception table's depth, plus the saved ``lasti``, plus the exception), with
:func:`dis.stack_effect` per instruction. It reproduces the compiler's ``co_stacksize`` on every
code object of this project and of the installed standard library, Trio and NumPy (320 718
code objects) but 6 test functions of the standard library, which it puts 1-2 slots lower; so
:func:`fit_stacksize` keeps a margin of :data:`MARGIN` slots and never exceeds atheris' figure.
Written here because no library computes it for a code object (``bytecode`` would, as a new
dependency for one function); :func:`dis._parse_exception_table` is CPython's own reader.
"""

from __future__ import annotations

import dis
import types

__all__ = ["MARGIN", "SMALL", "fit_stacksize", "max_stack_depth"]

#: slots added to the computed depth (the largest shortfall seen against the compiler is 2)
MARGIN = 8

_UNCONDITIONAL = {dis.opmap[n] for n in ("JUMP_FORWARD", "JUMP_BACKWARD", "JUMP_BACKWARD_NO_INTERRUPT",
                                          "RETURN_VALUE", "RAISE_VARARGS", "RERAISE") if n in dis.opmap}
_JUMPS = set(dis.hasjrel) | set(dis.hasjabs)
_RETURN_GENERATOR = dis.opmap.get("RETURN_GENERATOR", -1)


def max_stack_depth(code: types.CodeType) -> int:
    """The largest value-stack depth any path through ``code`` reaches (its own instructions only)."""
    instrs = list(dis.get_instructions(code))
    index = {ins.offset: i for i, ins in enumerate(instrs)}
    seen: dict[int, int] = {}
    work = [(0, 0)]
    for e in dis._parse_exception_table(code):  # type: ignore[attr-defined]
        work.append((index[e.target], e.depth + (1 if e.lasti else 0) + 1))
    deepest = 0
    while work:
        i, depth = work.pop()
        while i < len(instrs):
            if seen.get(i, -1) >= depth:
                break
            seen[i] = depth
            ins = instrs[i]
            op = ins.opcode
            arg = ins.arg if op >= dis.HAVE_ARGUMENT else None
            if op == _RETURN_GENERATOR:
                new = depth + 1  # the value the first send() brings, popped by the POP_TOP that follows
            elif op in _JUMPS:
                new = depth + dis.stack_effect(op, arg, jump=False)
            else:
                new = depth + dis.stack_effect(op, arg)
            deepest = max(deepest, depth, new)
            if op in _JUMPS:
                target = depth + dis.stack_effect(op, arg, jump=True)
                deepest = max(deepest, target)
                work.append((index[ins.argval], target))
            if op in _UNCONDITIONAL:
                break
            depth = new
            i += 1
    return deepest


#: a code object with at most this many slots is left as it is (256 bytes: walking it costs more at
#: start-up than its frames cost later)
SMALL = 32


def fit_stacksize(code: types.CodeType) -> types.CodeType:
    """``code`` and the code objects nested in it with ``co_stacksize`` = computed depth + :data:`MARGIN`
    (never more than it was; those of at most :data:`SMALL` slots as they are)."""
    consts = tuple(fit_stacksize(c) if isinstance(c, types.CodeType) else c for c in code.co_consts)
    size = code.co_stacksize if code.co_stacksize <= SMALL else min(code.co_stacksize, max_stack_depth(code) + MARGIN)
    if size == code.co_stacksize and consts == code.co_consts:
        return code
    return code.replace(co_consts=consts, co_stacksize=size)
