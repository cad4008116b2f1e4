"""Throughput of the streaming function-token parser vs expat, both fed 4-character chunks.

Prints MB/s (characters/1e6 per second) for a ~10 MB stream of realistic function-token text
(speech mixed with tags, nested elements, references), for ``FunctionTokenParser`` in strict and
lenient mode and for ``xml.parsers.expat`` (ParserCreate + Parse on the same chunks, with handlers
that build comparable event tuples), and the ratio.

    python bench/bench_parser.py [--mb 10] [--chunk 4]
"""

from __future__ import annotations

import argparse
import time
import xml.parsers.expat

from host.shell.parser import FunctionTokenParser

SAMPLE = (
    "Sure! Let me show you what I can do. "
    '<face_emo emo="happy"/><speak rate="1.0">Hello there, I&apos;m CoCo.</speak>\n'
    '<head_nod times="3" speed="0.8">Nodding while I talk &amp; wag my tail.'
    '<tail_wag duration="2.5"/></head_nod>\n'
    '<walk direction="forward" steps="4" speed="fast"/><wait/>'
    "Now I will sit down and wave my front-left paw.\n"
    '<sit/><paw_wave leg="front_left" times="2"/>'
    '<music song="happy_birthday" loop="true"><dance style="twist" duration="10"/></music>\n'
)


def make_stream(mb: float) -> str:
    n = int(mb * 1e6) // len(SAMPLE) + 1
    return SAMPLE * n


def chunks_of(s: str, k: int) -> list[str]:
    return [s[i : i + k] for i in range(0, len(s), k)]


def bench_ours(chunks: list[str], strict: bool) -> tuple[float, int]:
    t0 = time.perf_counter()
    p = FunctionTokenParser(strict=strict)
    feed = p.feed
    count = 0
    for c in chunks:
        count += len(feed(c))
    count += len(p.close())
    return time.perf_counter() - t0, count


def bench_expat(chunks: list[str]) -> tuple[float, int]:
    t0 = time.perf_counter()
    out: list[tuple] = []
    p = xml.parsers.expat.ParserCreate()
    p.StartElementHandler = lambda n, a: out.append(("s", n, a))
    p.EndElementHandler = lambda n: out.append(("e", n))
    p.CharacterDataHandler = lambda d: out.append(("t", d))
    p.Parse("<root>", False)
    parse = p.Parse
    for c in chunks:
        parse(c, False)
    parse("</root>", True)
    return time.perf_counter() - t0, len(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=10.0)
    ap.add_argument("--chunk", type=int, default=4)
    args = ap.parse_args()
    s = make_stream(args.mb)
    chunks = chunks_of(s, args.chunk)
    mb = len(s) / 1e6
    print(f"stream: {mb:.1f} M chars in {len(chunks)} chunks of {args.chunk}")
    te, ne = bench_expat(chunks)
    print(f"expat                    : {mb / te:7.2f} MB/s  ({te:.2f} s, {ne} events)")
    for strict in (True, False):
        t, n = bench_ours(chunks, strict)
        name = "strict" if strict else "lenient"
        print(
            f"FunctionTokenParser {name:7s}: {mb / t:7.2f} MB/s  ({t:.2f} s, {n} events)"
            f"  ratio to expat {te / t:.2f}x"
        )
    t, n = bench_ours(chunks_of(s, 4096), True)
    print(f"FunctionTokenParser 4 KiB chunks: {mb / t:7.2f} MB/s  ({t:.2f} s, {n} events)")


if __name__ == "__main__":
    main()
