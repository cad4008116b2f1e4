"""The second round of fuzz speed-ups (issue 17) keeps every check: what each one changes is tested here.

Fitted stack sizes of instrumented code (:mod:`host.tools.fuzz.stackdepth`), the hook-free copies used
for the second run of the same code (:func:`host.tools.fuzz.harness.without_hooks`), the shell's Trio in
guest mode (:class:`host.tools.fuzz.shell.GuestLoop`), the shell's and CAN target's remembered or narrowed
checks still catching a fault, the first time, from the input alone.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import types
from pathlib import Path

import pytest

pytest.importorskip("atheris", reason="the fuzz extra is not installed (pip install -e '.[fuzz]')")

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent


def _code_objects(path: Path) -> list[types.CodeType]:
    out: list[types.CodeType] = []
    stack = [compile(path.read_text(encoding="utf-8"), str(path), "exec")]
    while stack:
        c = stack.pop()
        out.append(c)
        stack += [k for k in c.co_consts if isinstance(k, types.CodeType)]
    return out


def test_max_stack_depth_is_the_compilers() -> None:
    """On every code object of the code the targets instrument, the computed depth is CPython's own."""
    from host.tools.fuzz.stackdepth import max_stack_depth

    files = [*sorted((ROOT / "protocol").rglob("*.py")), *sorted((ROOT / "host" / "shell").rglob("*.py")),
             *sorted((ROOT / "firmware_sim").glob("*.py"))]
    codes = [c for f in files for c in _code_objects(f)]
    assert len(codes) > 1000
    wrong = [(c.co_filename, c.co_name, max_stack_depth(c), c.co_stacksize) for c in codes
             if max_stack_depth(c) != c.co_stacksize]
    assert not wrong, wrong[:5]


def test_instrumented_parser_has_a_fitted_stack_and_parses_as_the_plain_one() -> None:
    """In a fresh process: atheris gives the parser's ``_scan`` thousands of stack slots; fitted, it
    has a few dozen, and the instrumented parser (hooks, fitted stack) yields the events of the plain
    source on every shell seed, fed in chunks, strict and lenient."""
    code = (
        "import pathlib\n"
        "from host.tools.fuzz.harness import instrument_only, without_hooks\n"
        "with instrument_only(['host.shell']):\n"
        "    import host.shell.parser as P\n"
        "scan = P.FunctionTokenParser._scan.__code__\n"
        "assert '__ATHERIS_INSTRUMENTED__' in scan.co_consts and scan.co_stacksize < 64, scan.co_stacksize\n"
        "Plain = without_hooks(P.FunctionTokenParser)\n"
        "def events(cls, text, strict):\n"
        "    p, out = cls(strict=strict), []\n"
        "    try:\n"
        "        for i in range(0, len(text), 7):\n"
        "            out += p.feed(text[i:i + 7])\n"
        "        out += p.close()\n"
        "    except P.ParseError as e:\n"
        "        out += ['error', e.message]\n"
        "    return out\n"
        "n = 0\n"
        f"for f in sorted(pathlib.Path({str(HERE / 'shell' / 'corpus')!r}).glob('*')):\n"
        "    text = f.read_bytes()[1:-4].decode('utf-8', 'replace') + '<a b=\"1\"><c/></d>&bad;'\n"
        "    for strict in (True, False):\n"
        "        assert events(P.FunctionTokenParser, text, strict) == events(Plain, text, strict), f\n"
        "        n += 1\n"
        "print(n)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120,
                          check=False)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert int(proc.stdout.split()[-1]) >= 100


def test_without_hooks_recompiles_the_methods_over_the_module_globals(monkeypatch: pytest.MonkeyPatch) -> None:
    import protocol.framing as framing
    from host.tools.fuzz.harness import without_hooks
    from protocol.messages import Heartbeat

    Plain = without_hooks(framing.FrameDecoder)
    assert issubclass(Plain, framing.FrameDecoder)
    assert Plain.feed is not framing.FrameDecoder.feed and Plain.feed.__code__.co_code == framing.FrameDecoder.feed.__code__.co_code
    assert isinstance(vars(Plain)["pending"], property)
    wire = framing.encode_frame(Heartbeat(9), 3)
    assert [f.raw for f in Plain().feed(wire * 2)] == [wire, wire]
    seen: list[bytes] = []
    real = framing._decode_block
    monkeypatch.setattr(framing, "_decode_block", lambda b, r, s=framing.WIRE_SCHEMA_16: seen.append(b) or real(b, r, s))
    Plain().feed(wire)
    assert seen == [wire[:-1]]  # a name patched in the module is the one the copy calls


def test_guest_loop_runs_on_virtual_time_on_its_thread() -> None:
    """In a thread of its own (a guest run makes its thread count as inside Trio while it lives)."""
    import trio

    from host.tools.fuzz.shell import GuestLoop

    threads_before = threading.active_count()
    seen: dict[str, object] = {}

    def body() -> None:
        loop = GuestLoop.shared()
        assert GuestLoop.shared() is loop

        async def nap(seconds: float) -> tuple[float, int]:
            t0 = trio.current_time()
            await trio.sleep(seconds)
            return trio.current_time() - t0, threading.get_ident()

        async def fail() -> None:
            await trio.sleep(1)
            raise AssertionError("from the loop")

        seen["nap"] = loop.run(nap, 600.0)  # virtual time
        try:
            loop.run(fail)
        except AssertionError as e:
            seen["raised"] = str(e)
        seen["again"] = loop.run(nap, 1.5)[0]
        seen["threads"] = threading.active_count()
        loop.close()
        seen["closed"] = GuestLoop.shared() is not loop
        GuestLoop.shared().close()

    t = threading.Thread(target=body)
    t.start()
    t.join(60)
    assert seen["nap"] == (600.0, t.ident)  # on the calling thread
    assert seen["raised"] == "from the loop" and seen["again"] == 1.5
    assert seen["threads"] == threads_before + 1  # this thread only: no Trio thread, no I/O thread
    assert seen["closed"]


def test_guest_loop_leaves_sigint_alone() -> None:
    code = (
        "import signal\n"
        "from host.tools.fuzz.shell import GuestLoop\n"
        "before = signal.getsignal(signal.SIGINT)\n"
        "GuestLoop.shared()\n"
        "assert signal.getsignal(signal.SIGINT) is before\n"
    )
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, timeout=60, check=True)


def test_shell_target_still_checks_a_new_element_after_warm_up(monkeypatch: pytest.MonkeyPatch) -> None:
    """Elements already mapped and checked are remembered; an element seen for the first time is
    mapped and checked for real, after a warm-up and on its own in a fresh process-like load."""
    import host.tools.fuzz.validate as validate

    real = validate.conforms
    monkeypatch.setattr(validate, "conforms", lambda v, ann: v != -77 and real(v, ann))  # a "bug" at -77
    from host.tools.fuzz.shell import load

    one_input = load(False)
    for p in sorted((HERE / "shell" / "corpus").glob("*")):
        one_input(p.read_bytes())
    one_input(b'\x00<rotate angle="-90"/>\0\0\0\0')
    with pytest.raises(AssertionError, match="angle=-77"):
        one_input(b'\x00<rotate angle="-77"/>\0\0\0\0')
    with pytest.raises(AssertionError, match="angle=-77"):
        load(False)(b'\x00<rotate angle="-77"/>\0\0\0\0')  # replayed alone


def test_shell_target_did_you_mean_is_the_registrys() -> None:
    from host.tools.fuzz.shell import load
    from host.shell.registry import Registry, UnknownFunction

    one_input = load(False)
    one_input(b"\x00<rotat/><rotat/>\0\0\0\0")
    registry = one_input.__closure__  # the target's registry, found through the closure cells
    fuzz_registry = next(c.cell_contents for c in registry or () if isinstance(c.cell_contents, Registry))
    plain = Registry(fuzz_registry.modules())
    for name in ("rotat", "rotat", "head_ac", "zzz"):
        with pytest.raises(UnknownFunction) as got:
            fuzz_registry.resolve(name)
        with pytest.raises(UnknownFunction) as want:
            plain.resolve(name)
        assert got.value.suggestions == want.value.suggestions


def test_can_target_still_bounds_assemblies(monkeypatch: pytest.MonkeyPatch) -> None:
    """The bounds are checked after every frame the decoder takes (and at the end of the input): a
    decoder keeping three assemblies of one function code is caught."""
    import protocol.can.decoder as decoder
    from host.tools.fuzz.can_decoder import load
    from protocol.can.ids import FunctionCode

    fn = list(FunctionCode).index(FunctionCode.SERVO_FRAME)
    data = b"\x00" + b"".join(bytes([8, fn, 8]) + (seq << 5).to_bytes(2, "little") + bytes(6) for seq in (1, 2, 3))
    one_input = load(False)
    one_input(data)  # the real decoder drops the oldest of three
    monkeypatch.setattr(decoder, "MAX_ASSEMBLIES", 3)
    with pytest.raises(AssertionError):
        one_input(data)


def test_can_decoder_set_lookup_is_is_mine() -> None:
    """The decoder's one-lookup "mine" test accepts exactly the ids :meth:`CanDecoder.is_mine` does."""
    from protocol.can.decoder import CanDecoder
    from protocol.can.frame import CanFrame

    for node in (1, 5, 6, 127):
        for receiver in ("board", "host"):
            dec = CanDecoder(node, receiver)
            assert dec._mine == {aid for aid in range(0x800) if dec.is_mine(CanFrame(aid, b""))}
