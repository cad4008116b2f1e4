"""A bad argument is refused before the command does anything: exit status 2, one line, nothing lost.

Each row was found only after a side effect (the last kind is found only when the board opens a device;
``run`` then puts the earlier run's artefacts back, :class:`host.commands.outarg.EarlierRun`): ``run --xml ... --llm bogus:x`` cleared the earlier run's
artefacts in ``--out`` and started the board, then exited 1; a ``--mount-mcp`` server that cannot start
or be reached, and a ``--servo-bus`` device that is not there, were found once the board ran (``--out``
cleared or its frame logs truncated; ``mcp`` printed ~100 lines of exception groups, exit 1); ``eval
--paper-model`` with a name the paper lacks was noticed in eval.md after the sweep; ``render --out``,
``pose``/``estop --log`` and ``vcan --run-dir`` that cannot be written failed after the work (ffmpeg's
report, exit 1), after the move (the log silently dropped) or with a traceback.

The rows run in-process through :func:`host.cli.main` (nothing starts when they pass); one subprocess
checks ``mcp``'s one line for a server that fails after the board started.
"""

from __future__ import annotations

import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from support.cli_refusal import refused


pytestmark = pytest.mark.timeout(120)

ROOT = Path(__file__).resolve().parents[2]

#: an earlier run's files in the --out folder (and one of the user's), each with its own bytes
EARLIER = {"summary.json": b'{"outcome": "done"}\n', "timeline.json": b"[]\n", "host_frames.jsonl": b'{"t": 1}\n',
           "board_frames.jsonl": b'{"t": 2}\n', "run.mcap": b"\x89MCAP0\r\n", "board.stderr": b"board: ok\n",
           "run.mp4": b"\x00\x00\x00\x18ftypmp42", "transcript.json": b"{}\n", "config.json": b'{"llm": "x"}\n',
           "results.jsonl": b"", "notes.txt": b"mine\n"}

NOD = '<head_act action="nod"/>'
REFUSED_PORT = "{REFUSED_PORT}"  # a localhost port bound but not listening: a connection is refused


@pytest.fixture
def refused_port() -> Iterator[int]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


#: (argv with OUT for the earlier run's folder, what the one line says)
ROWS: list[tuple[tuple[str, ...], str]] = [
    # the LLM spec: checked before --out is cleared (was exit 1 after clearing it and starting the board)
    (("run", "--xml", NOD, "--llm", "bogus:x"), "unknown LLM spec 'bogus:x'"),
    (("run", "--task", "1", "--llm", "openai:"), "no model; use openai:MODEL"),
    (("run", "--task", "1", "--llm", "scripted:x"), "'scripted' takes no argument"),
    (("run", "--xml", NOD, "--llm", "anthropic:claude-sonnet-4-0"), "answers --prompt TEXT"),
    # --mount-mcp: a program that is not there, a URL nothing listens on (was: found after the board started)
    (("run", "--task", "1", "--mount-mcp", "w=/no/such/server"), "w=/no/such/server: cannot start the server"),
    (("run", "--task", "1", "--mount-mcp", "w=no-such-mcp-server-program"), "no program 'no-such-mcp-server-program'"),
    (("run", "--task", "1", "--mount-mcp", f"w=http://127.0.0.1:{REFUSED_PORT}/mcp"), "connection refused"),
    (("chat", "--replies", "{REPLIES}", "--llm", "scripted:x"), "'scripted' takes no argument"),
    (("chat", "--replies", "{REPLIES}", "--mount-mcp", "w=/no/such/server"), "cannot start the server"),
    (("mcp", "--mount-mcp", "w=/no/such/server"), "cannot start the server"),
    # --servo-bus: a device that is not there (was: the board's refusal, after --out was cleared)
    (("run", "--task", "1", "--servo-bus", "/dev/no-such-adapter"), "there is no device '/dev/no-such-adapter'"),
    (("demo", "--no-video", "--servo-bus", "/dev/no-such-adapter"), "there is no device"),
    (("chat", "--replies", "{REPLIES}", "--servo-bus", "{OUT}"), "is not a serial device"),
    # a start the board refuses (a character device that is no serial port): found only when the board opens it;
    # the earlier run's artefacts, set aside meanwhile, come back (were: removed before the board started)
    (("run", "--task", "1", "--servo-bus", "/dev/null"), "servo bus /dev/null"),
    (("chat", "--replies", "{REPLIES}", "--servo-bus", "/dev/null"), "servo bus /dev/null"),
    # eval: a paper column the paper lacks (was: eval.md's paper column empty after the sweep)
    (("eval", "--llm", "ground-truth", "--tasks", "1", "--trials", "1", "--no-run", "--paper-model", "GPT-9"),
     "--paper-model 'GPT-9': the paper's columns are"),
]

#: rows whose command has no run folder: (argv, what the one line says)
FILE_ROWS: list[tuple[tuple[str, ...], str]] = [
    (("render", "{OUT}", "--out", "/proc/x.mp4"), "argument --out: /proc/x.mp4 cannot be created"),
    (("render", "{OUT}", "--out", "/dev/null"), "/dev/null is a device, not a file"),
    (("render", "{OUT}", "--out", "{OUT}/no/such/x.mp4"), "there is no folder"),
    (("pose", "--link", "/dev/null", "--pose", "stand", "--log", "{OUT}"), "argument --log:"),
    (("estop", "--link", "/dev/null", "--log", "/proc/x.jsonl"), "argument --log: /proc/x.jsonl cannot be created"),
    (("vcan", "--uml", "--run-dir", "/proc/x", "--", "true"), "argument --run-dir: /proc/x cannot be created"),
]

_COMMON = {"run": ("--lockstep", "--no-live"), "chat": ("--lockstep", "--no-live"), "demo": ("--lockstep", "--no-live"),
           "mcp": ("--lockstep",), "eval": ()}


def _earlier_run(folder: Path) -> dict[str, bytes]:
    folder.mkdir(parents=True)
    for name, data in EARLIER.items():
        (folder / name).write_bytes(data)
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.fixture(autouse=True)
def _no_llm_environment(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    for name in ("GHOSTSHELL_LLM_MODEL", "GHOSTSHELL_LLM_API_KEY", "OPENAI_API_KEY", "ANTHROPIC_API_KEY"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.chdir(tmp_path)


@pytest.mark.parametrize(("argv", "says"), ROWS, ids=[" ".join(a)[:70] for a, _ in ROWS])
def test_a_bad_argument_leaves_the_earlier_run_as_it_was(argv: tuple[str, ...], says: str, tmp_path: Path,
                                                         refused_port: int,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "earlier"
    kept = _earlier_run(out)
    replies = tmp_path / "replies.txt"
    replies.write_text(NOD + "\n", encoding="utf-8")
    args = [a.replace("{REPLIES}", str(replies)).replace("{OUT}", str(out)).replace(REFUSED_PORT, str(refused_port))
            for a in argv]
    line = refused((*args, *_COMMON[argv[0]], "--out", str(out)), capsys, quiet_stdout=True)
    assert says in line, line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == kept  # byte-identical, nothing added


@pytest.mark.parametrize(("argv", "says"), FILE_ROWS, ids=[" ".join(a)[:70] for a, _ in FILE_ROWS])
def test_an_output_file_that_cannot_be_written_is_refused_first(argv: tuple[str, ...], says: str, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "run"
    folder.mkdir()
    line = refused(tuple(a.replace("{OUT}", str(folder)) for a in argv), capsys, quiet_stdout=True)
    assert says in line, line
    assert list(folder.iterdir()) == []


def test_a_firmware_whose_emulator_is_not_installed_is_refused_first(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    """``--firmware qemu`` without qemu-system-arm on PATH: was the board's refusal after --out was cleared."""
    out = tmp_path / "earlier"
    kept = _earlier_run(out)
    monkeypatch.setenv("PATH", str(tmp_path / "no-tools"))
    line = refused(("run", "--task", "1", "--lockstep", "--no-live", "--firmware", "qemu", "--out", str(out)), capsys, quiet_stdout=True)
    assert "qemu-system-arm, which is not installed" in line, line
    assert {p.name: p.read_bytes() for p in out.iterdir()} == kept


def test_a_tour_whose_link_cannot_be_opened_leaves_no_folder(tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "tour"
    line = refused(("tour", "--lockstep", "--link", "can:slcan:/dev/no-such-adapter", "--out", str(out)), capsys, quiet_stdout=True)
    assert "cannot open CAN bus" in line, line
    assert not out.exists(), list(out.iterdir())  # was: the folder with an empty host.log


def test_eval_refuses_a_server_it_cannot_start_before_making_its_folder(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "eval"
    line = refused(("eval", "--llm", "ground-truth", "--tasks", "1", "--trials", "1", "--no-run",
                     "--mount-mcp", "w=/no/such/server", "--out", str(out)), capsys)
    assert "cannot start the server" in line
    assert not out.exists()  # was: the folder and its config.json, then the refusal


def test_an_earlier_run_set_aside_comes_back_exactly_or_goes(tmp_path: Path) -> None:
    from host.commands.outarg import EarlierRun, session_start_files

    out = tmp_path / "run"
    out.mkdir()
    kept = {"summary.json": b"1", "run.mp4": b"2", "notes.txt": b"3"}
    for name, data in kept.items():
        (out / name).write_bytes(data)
    earlier = EarlierRun(out)
    assert earlier.names == ["run.mp4", "summary.json"] and sorted(p.name for p in out.iterdir())[-1] == "notes.txt"
    for name in ("board.stderr", "board_frames.jsonl", "summary.json"):  # what a refused start began
        (out / name).write_bytes(b"refused")
    earlier.restore()
    assert {p.name: p.read_bytes() for p in out.iterdir()} == kept  # nothing of the refused start, nothing hidden
    earlier = EarlierRun(out, only=session_start_files())  # chat: only what its start overwrites
    assert earlier.names == []
    EarlierRun(out).discard()
    assert {p.name for p in out.iterdir()} == {"notes.txt"}


def test_a_spec_check_agrees_with_make_ghost(monkeypatch: pytest.MonkeyPatch) -> None:
    from host.ghost import GhostError, make_ghost
    from host.ghost.factory import check_spec

    for spec in ("bogus:x", "openai:", "anthropic", "scripted:x", ""):
        with pytest.raises(GhostError) as checked:
            check_spec(spec)
        with pytest.raises(GhostError) as built:
            make_ghost(spec, program=NOD)
        assert str(checked.value) == str(built.value)
    assert check_spec(" Scripted ") == "scripted"
    assert check_spec("openai:gpt-4o") == "openai:gpt-4o"
    monkeypatch.setenv("GHOSTSHELL_LLM_MODEL", "gpt-4o-mini")
    check_spec("openai")  # the model from the environment


def test_a_reachable_server_is_not_refused(refused_port: int) -> None:
    from host.mounts.spec import MountSpec, launch_problem

    assert launch_problem(MountSpec("w", command=("python", "server.py"))) is None  # ghostshell's interpreter
    assert launch_problem(MountSpec("w", command=("ghostshell", "mcp"))) is None
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        assert launch_problem(MountSpec("w", url=f"http://127.0.0.1:{s.getsockname()[1]}/mcp")) is None
    assert "connection refused" in (launch_problem(MountSpec("w", url=f"http://127.0.0.1:{refused_port}/mcp")) or "")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("argv", [("--lockstep", "--mount-mcp", "w=false"), ("--http", "{PORT}", "--link", "/dev/null")],
                         ids=["stdio, a server that exits", "http, a link that is no tty"])
def test_mcp_says_a_session_that_cannot_start_in_one_line(argv: tuple[str, ...], tmp_path: Path) -> None:
    """Found only when the session starts (``false`` starts and exits at once; /dev/null is a character device
    but no tty): the one line comes out of the server (was: ~100 lines of nested exception groups and exit 1
    over stdio; uvicorn's traceback and exit status 3 over HTTP)."""
    args = [a.replace("{PORT}", str(_free_port())) for a in argv]
    out = tmp_path / "earlier"
    kept = _earlier_run(out)
    p = subprocess.run([sys.executable, "-m", "host", "mcp", *args, "--out", str(out)],
                       capture_output=True, text=True, timeout=100, stdin=subprocess.DEVNULL, cwd=ROOT)
    assert {f.name: f.read_bytes() for f in out.iterdir()} == kept  # the frame logs the start truncated are back
    assert p.returncode == 2, p.stderr[-3000:]
    assert "Traceback" not in p.stderr and "ExceptionGroup" not in p.stderr, p.stderr[-3000:]
    errors = [ln for ln in p.stderr.splitlines() if ln.startswith("ghostshell mcp:")]
    assert len(errors) == 1 and ("--mount-mcp w=false" in errors[0] or "'/dev/null'" in errors[0]), p.stderr


def test_a_run_that_never_started_puts_the_earlier_run_back(tmp_path: Path) -> None:
    """A link that answers nothing (``loop://``: no CAPS within the handshake's 3 s) ends the start with a report of
    its own (exit 1): the earlier run's files still come back byte for byte and no hidden folder is left (it was:
    the files stayed in ``.ghostshell-earlier-*`` and the line named the failed start's artefacts)."""
    out = tmp_path / "out"
    before = _earlier_run(out)
    p = subprocess.run([sys.executable, "-m", "host", "run", "--xml", NOD, "--lockstep", "--no-plots", "--no-live",
                        "--link", "loop://", "--out", str(out)], capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert p.returncode == 1, p.stderr
    assert "no CAPS" in p.stderr and "Traceback" not in p.stderr + p.stdout
    assert "artefacts in" not in p.stdout  # the failed start's files are not what is left there
    assert {q.name: q.read_bytes() for q in out.iterdir()} == before


@pytest.mark.parametrize("argv", [("run", "--task", "26", "--lockstep", "--no-live"), ("tour", "--lockstep"),
                                  ("eval", "--llm", "ground-truth"), ("chat", "--llm", "scripted", "--lockstep")],
                         ids=lambda a: a[0])
def test_an_out_folder_that_is_a_dangling_link_is_refused(argv: tuple[str, ...], tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """``--out`` a symbolic link whose target does not exist: was a FileExistsError traceback (tour, eval) or
    ``[Errno 17] File exists`` with exit 1 (run, chat)."""
    link = tmp_path / "dangling"
    link.symlink_to(tmp_path / "nowhere")
    line = refused((*argv, "--out", str(link)), capsys, quiet_stdout=True)
    assert "symbolic link" in line and "does not exist" in line
    assert not (tmp_path / "nowhere").exists()
