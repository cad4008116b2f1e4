"""One exit-code table for every command (issue 16, item 3), run as a user runs the commands.

Status 2 (usage or bad input) for every row here: a bad argument, a missing/empty/garbage file, an
unknown name, a link spec or port that cannot be opened. Each row is a real ``python -m host ...``
process; it must fail before anything starts (no board, no run folder), with the problem in one
line on stderr (argparse's usage block no longer comes before it) and no traceback. The table covers every
command in :data:`host.cli.COMMANDS`, and each command also refuses an unknown option (so a command
added later gets at least that row without anyone remembering). The rows run a few at a time;
they are fast because nothing starts.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from host.cli import COMMANDS, EXIT_CODES

pytestmark = pytest.mark.timeout(300)


@dataclass(frozen=True)
class Row:
    argv: tuple[str, ...]
    says: str  # in the last stderr line
    status: int = 2


def _files(d: Path) -> dict[str, str]:
    """Input files of the table (made once): missing, empty, garbage, too large."""
    d.mkdir(parents=True, exist_ok=True)
    (d / "empty.xml").write_text("", encoding="utf-8")
    (d / "blank.xml").write_text(" \n\n\t\n", encoding="utf-8")
    (d / "latin1.xml").write_bytes(b"<say>caf\xe9</say>")
    (d / "prose.xml").write_text("All work and no play makes the robot a dull robot. " * 40_000, encoding="utf-8")
    (d / "calls.xml").write_text('<head_act action="nod"/>' * 20_000, encoding="utf-8")
    (d / "garbage.log").write_text("this is not a candump\nat all\n", encoding="utf-8")
    # a candump line with a 1 MB payload: no CAN frame (a new user's 25 MB one was decoded as one, 400 MB RSS)
    (d / "huge_line.log").write_text("(1.000000) vcan0 123#" + "AB" * 500_000 + "\n", encoding="utf-8")
    (d / "garbage.jsonl").write_text("{not json\n", encoding="utf-8")
    (d / "empty.jsonl").write_text("", encoding="utf-8")
    (d / "empty.log").write_text("", encoding="utf-8")
    (d / "bad_skills.json").write_text("[1, 2", encoding="utf-8")
    (d / "folder").mkdir(exist_ok=True)
    (d / "replies2.txt").write_text("<head_act/>\n---\n<wave/>\n", encoding="utf-8")
    (d / "regular.txt").write_text(KEPT, encoding="utf-8")  # given as --out: refused, left as it was
    return {k: str(d / k) for k in ("empty.xml", "blank.xml", "latin1.xml", "prose.xml", "calls.xml", "garbage.log", "huge_line.log",
                                    "garbage.jsonl", "empty.jsonl", "empty.log", "bad_skills.json", "folder",
                                    "replies2.txt", "regular.txt")} | {"missing": str(d / "missing.xml")}


#: link specs that cannot be opened here, each refused before anything starts, in every command with --link
BAD_LINKS = {
    "bogus": "no device 'bogus'",
    "/dev/pts/999": "no device '/dev/pts/999'",
    "/dev/null": "not a serial port or tty",
    "rfc2217://x": "needs HOST:PORT",
    "can:socketcan:vcan0": "cannot open CAN bus can:socketcan:vcan0",
    "can:": "no interface given and none configured for python-can",  # python-can's config, read without a bus
}

KEPT = "a file that is not a run folder\n"
TAKEN_PORT = "{TAKEN_PORT}"  # a localhost TCP port another socket listens on while the table runs


def _rows(f: dict[str, str], out: str) -> list[Row]:
    rows: list[Row] = []
    link_commands = {
        "run": ["run", "--task", "1", "--lockstep", "--no-live", "--out", out],
        "demo": ["demo", "--lockstep", "--no-live", "--no-video", "--out", out],
        "chat": ["chat", "--replies", f["replies2.txt"], "--lockstep", "--no-live", "--out", out],
        "tour": ["tour", "--lockstep", "--out", out],
        "pose": ["pose", "--pose", "stand"],
        "estop": ["estop"],
        "mcp": ["mcp", "--lockstep", "--out", out],
        "firmware check": ["firmware", "check"],
    }
    for name, argv in link_commands.items():
        for spec, says in BAD_LINKS.items():
            if spec == "/dev/null" and name == "mcp":
                continue  # mcp reaches the open only once serving: its /dev/null row is the host's (run, chat...)
            rows.append(Row((*argv, "--link", spec), says))
    rows += [
        # board: its own parser (argparse) and its own refusal of a link it cannot serve
        Row(("board", "--link", "rfc2217://x"), "needs HOST:PORT"),
        Row(("board", "--link", "bogus", "--lockstep"), "cannot open link 'bogus'"),
        Row(("board", "--link", "pty", "--rate", "0"), "must be > 0"),
        Row(("board", "--link", "pty", "--scene", "moon"), "no scene 'moon'"),
        # the board modelled any --baud it was given (run's bound, shared through protocol.wiremodel)
        Row(("board", "--link", "pty", "--baud", "99999999999"), "must be 1..12000000 bit/s"),
        Row(("board", "--link", "can:socketcan:vcan0"), "cannot open CAN bus can:socketcan:vcan0"),
        # pose / estop
        Row(("pose", "--link", "pty", "--pose", "stand"), "a link the emulated board creates"),
        Row(("pose", "--link", "/dev/null", "--pose", "moonwalk"), "no pose 'moonwalk'"),
        Row(("pose", "--link", "/dev/null", "--pose", "stand", "--duration", "-1"), "must be >= 0 seconds"),
        Row(("pose", "--link", "/dev/null", "--pose", "stand", "--baud", "0"), "must be 1..12000000 bit/s"),
        # was pyserial's OverflowError traceback once the run opened the port
        Row(("run", "--task", "14", "--baud", "99999999999", "--out", out), "must be 1..12000000 bit/s"),
        Row(("estop", "--link", "pty"), "a link the emulated board creates"),
        # firmware: build's own parser and refusals (python -m firmware_sim.cfirmware), check's link
        Row(("firmware", "build", "--target", "avr"), "invalid choice: 'avr'"),
        Row(("firmware", "build", "--target", "mps2", "--robot", "no-such-robot"), "no robot 'no-such-robot'"),
        Row(("firmware", "build", "--target", "mps2", "--out", f["regular.txt"]), "is a regular file, not a folder"),
        Row(("firmware", "check", "--link", "pty"), "a link the emulated board creates"),
        # demo / tour
        Row(("demo", "--task", "999", "--lockstep", "--out", out), "no runnable task 999"),
        Row(("demo", "--scene", "moon", "--out", out), "--scene 'moon'"),
        Row(("demo", "--max-board-s", "-5", "--out", out), "must be >= 0"),
        Row(("tour", "--duration", "soon"), "expected a number of seconds"),
        Row(("tour", "--robot", "no-such-robot"), "no-such-robot"),
        # log
        Row(("log", "decode", f["missing"]), "cannot read"),
        Row(("log", "decode", f["garbage.jsonl"], "--type", "BOGUS"), "--type BOGUS: no such message type"),
        Row(("log", "decode", f["garbage.log"]), "is not a candump -L line"),
        Row(("log", "decode", f["huge_line.log"]), "more than one CAN frame's line can have"),
        Row(("replay", f["huge_line.log"]), "more than one CAN frame's line can have"),
        Row(("log", "decode", f["garbage.jsonl"]), "is not a frame log"),
        Row(("log", "decode", f["empty.jsonl"]), "holds no records"),
        Row(("log", "decode", f["empty.log"]), "holds no CAN frames"),
        Row(("log",), "required"),
        # a --link whose log format is not the file's: was python-can's "No read support" ValueError
        Row(("log", "decode", f["garbage.jsonl"], "--link", "can:virtual"), "records a CAN log (.log, .asc"),
        Row(("log", "decode", f["garbage.log"], "--link", "pty"), "records a serial JSON Lines log (.jsonl)"),
        # replay
        Row(("replay", f["missing"]), "no such log"),
        Row(("replay", f["folder"]), "no host frame log"),
        Row(("replay", f["empty.jsonl"]), "holds no host-to-board messages"),
        Row(("replay", f["garbage.log"], "--out", out), "cannot replay"),
        # prompt
        Row(("prompt", "--interface", "no.such.module:x"), "cannot load interface"),
        Row(("prompt", "--format", "yaml"), "invalid choice"),
        Row(("prompt", "--robot", "no-such-robot"), "no-such-robot"),
        Row(("prompt", "--skills", f["bad_skills.json"]), "cannot read the skill library"),
        # dsbc
        Row(("dsbc", "@" + f["missing"], "<a/>"), "cannot read it"),
        Row(("dsbc", "@" + f["empty.xml"], "<a/>"), "is empty"),
        Row(("dsbc", "", "<a/>"), "GT is empty"),
        Row(("dsbc", "<a", "<a/>"), "ground truth"),
        # run: inputs refused before anything starts (the cases)
        Row(("run", "--xml-file", f["missing"], "--out", out), "cannot read it"),
        Row(("run", "--xml-file", f["empty.xml"], "--out", out), "is empty"),
        Row(("run", "--xml-file", f["blank.xml"], "--out", out), "is empty"),
        Row(("run", "--xml-file", f["latin1.xml"], "--out", out), "is not UTF-8 text"),
        Row(("run", "--xml-file", f["folder"], "--out", out), "is a folder"),
        Row(("run", "--xml-file", f["prose.xml"], "--out", out), "more than 1,000,000 characters of text"),
        Row(("run", "--xml-file", f["calls.xml"], "--out", out), "more than 5,000 calls"),
        Row(("run", "--xml", "", "--out", out), "--xml is empty"),
        Row(("run", "--prompt", " ", "--llm", "openai:gpt-4o-mini", "--out", out), "--prompt is empty"),
        Row(("run", "--prompt", "wave", "--out", out), "needs a real LLM"),
        Row(("run", "--out", out), "one of the arguments --task --xml --xml-file --prompt is required"),
        Row(("run", "--task", "999", "--out", out), "no runnable task 999"),
        Row(("run", "--task", "1", "--tokens-per-s", "0", "--out", out), "must be > 0"),
        Row(("run", "--task", "1", "--max-log-mb", "lots", "--out", out), "expected a number"),
        Row(("run", "--task", "1", "--baud", "fast", "--out", out), "expected a whole number of bit/s"),
        Row(("run", "--task", "1", "--vocabulary", "klingon", "--out", out), "--vocabulary 'klingon'"),
        # run: a skill library that cannot be read is bad input (it was exit status 1)
        Row(("run", "--task", "1", "--skills", f["bad_skills.json"], "--out", out), "cannot read the skill library"),
        Row(("run", "--task", "1", "--skills", f["folder"], "--out", out), "it is a folder"),
        Row(("demo", "--skills", f["bad_skills.json"], "--out", out), "cannot read the skill library"),
        # --mount-mcp NAMEs are checked against the robot's modules before the board starts (was: after it
        # started and truncated the folder's frame logs)
        Row(("run", "--task", "26", "--lockstep", "--no-live", "--out", out, "--mount-mcp", "head=x"),
            "'head' is already a module or channel"),
        Row(("run", "--task", "1", "--lockstep", "--no-live", "--out", out, "--mount-mcp", "a=x", "--mount-mcp", "a=y"),
            "NAME given twice"),
        Row(("chat", "--replies", f["replies2.txt"], "--out", out, "--mount-mcp", "face=x"),
            "'face' is already a module or channel"),
        Row(("mcp", "--lockstep", "--out", out, "--mount-mcp", "head=x"), "'head' is already a module or channel"),
        Row(("eval", "--llm", "ground-truth", "--tasks", "1", "--out", out, "--mount-mcp", "a=x", "--mount-mcp", "a=y"),
            "NAME given twice"),
        # a port another server listens on: one line before the board starts (mcp was ~300 lines of tracebacks)
        Row(("mcp", "--http", TAKEN_PORT, "--lockstep", "--out", out), f"port {TAKEN_PORT} is in use"),
        Row(("run", "--task", "1", "--lockstep", "--no-live", "--foxglove", TAKEN_PORT, "--out", out),
            f"port {TAKEN_PORT} is in use"),
        # chat
        Row(("chat", "--replies", f["missing"], "--out", out), "cannot read it"),
        Row(("chat", "--replies", f["empty.xml"], "--out", out), "is empty"),
        Row(("chat", "--replies", f["prose.xml"], "--out", out), "more than 1,000,000 characters of text"),
        Row(("chat", "--turns", f["replies2.txt"], "--out", out), "for --turns use --llm openai:MODEL"),
        Row(("chat", "--max-steps", "0", "--out", out), "--max-steps must be >= 1"),
        # skills
        Row(("skills", "--skills", f["bad_skills.json"], "list"), "cannot read the skill library"),
        Row(("skills", "--skills", f["empty.jsonl"] + ".none", "show", "nope"), "unknown skill 'nope'"),
        Row(("skills",), "required"),
        # mcp
        Row(("mcp", "--http", "99999"), "a TCP port is 1-65535"),
        Row(("mcp", "--http", "0"), "a TCP port is 1-65535"),
        Row(("mcp", "--http", "web"), "expected a TCP port number"),
        Row(("mcp", "--scene", "moon", "--out", out), "--scene 'moon'"),
        # eval
        Row(("eval", "--llm", "scripted", "--tasks", "1-3", "--out", out), "--llm scripted replays --replies FILE"),
        Row(("eval", "--llm", "scripted", "--replies", f["missing"], "--tasks", "1-3", "--out", out), "cannot read it"),
        Row(("eval", "--llm", "scripted", "--replies", f["empty.xml"], "--tasks", "1-3", "--out", out), "is empty"),
        Row(("eval", "--llm", "scripted", "--replies", f["replies2.txt"], "--tasks", "1-3", "--out", out),
            "holds 2 replies for 3 task(s)"),
        Row(("eval", "--llm", "ground-truth", "--replies", f["replies2.txt"], "--out", out), "--replies needs --llm scripted"),
        Row(("eval", "--llm", "ground-truth", "--trials", "0", "--out", out), "must be at least 1"),
        Row(("eval", "--llm", "ground-truth", "--tasks", "99", "--out", out), "99"),
        Row(("eval", "--llm", "nosuchprovider:x", "--out", out), "nosuchprovider"),
        # render
        Row(("render", f["missing"]), "does not exist"),
        Row(("render", f["folder"]), "not found"),
        Row(("render", f["folder"], "--fps", "5"), "invalid choice"),
        Row(("render", f["folder"], "--workers", "0"), "must be >= 1"),
        # fuzz
        Row(("fuzz", "no-such-target"), "unknown target 'no-such-target'"),
        Row(("fuzz", "serial-decoder", "--seconds", "0"), "--seconds must be at least 1, got 0"),
        Row(("fuzz", "serial-decoder", "--jobs", "-2"), "--jobs must be at least 1, got -2"),
        # dbc, robots
        Row(("dbc", "--robot", "no-such-robot"), "no robot 'no-such-robot'"),
        Row(("robots", "show", "no-such-robot"), "no robot 'no-such-robot'"),
        Row(("robots", "new", "x"), "required: --mjcf"),
        Row(("robots", "new", "x", "--mjcf", f["missing"], "--robots-dir", OUT), "missing.xml"),
        # vcan
        Row(("vcan",), "no COMMAND given"),
        Row(("vcan", "--ifaces", "a b", "--", "true"), "is not a list of interface names"),
        Row(("vcan", "--timeout", "-1", "--", "true"), "above 0"),
        Row(("vcan", "--", "no-such-command-anywhere"), "command not found", status=127),
    ]
    # --out that cannot be a folder of artefacts: every command's, one validator (host.commands.outarg)
    regular = f["regular.txt"]
    out_commands = {
        "run": ["run", "--task", "1", "--lockstep", "--no-live"],
        "demo": ["demo", "--lockstep", "--no-live", "--no-video"],
        "chat": ["chat", "--replies", f["replies2.txt"], "--lockstep", "--no-live"],
        "replay": ["replay", f["garbage.jsonl"]],
        "tour": ["tour", "--lockstep"],
        "mcp": ["mcp", "--lockstep"],
        "eval": ["eval", "--llm", "ground-truth", "--tasks", "1", "--trials", "1"],
        "fuzz": ["fuzz", "serial-decoder"],
    }
    for argv in out_commands.values():
        rows.append(Row((*argv, "--out", regular), "is a regular file, not a folder"))
    rows += [
        Row((*out_commands["run"], "--out", "/dev/null"), "/dev/null is a device, not a folder"),
        Row((*out_commands["run"], "--out", regular + "/sub"), "is a regular file, not a folder"),
        Row((*out_commands["mcp"], "--out", "/proc/x"), "/proc/x cannot be created: /proc takes no new folder"),
        Row((*out_commands["tour"], "--out", "/proc"), "/proc is a folder this process cannot write in"),
        Row((*out_commands["eval"], "--out", "/dev/null"), "/dev/null is a device, not a folder"),
        Row((*out_commands["fuzz"], "--corpus", regular), "is a regular file, not a folder"),
    ]
    # every command: an unknown option is argparse's usage error (vcan hands what follows -- to COMMAND), on
    # a line that names the command (it named only "ghostshell" before host.cli.OneLineParser.parse_args)
    rows += [Row((name, "--no-such-option"), f"ghostshell {name}: error:") for name in COMMANDS]
    rows += [Row(("eval", "--llm", "nonsense"), "or ground-truth (offline)"),
             Row(("pose", "--link", "/dev/no-such-tty", "--pose", "stand"), "/dev/ttyUSB0 or a pyserial URL")]
    return rows


OUT = "{OUT}"  # each row's own run folder (it must not exist afterwards)


@dataclass
class Result:
    row: Row
    status: int
    stderr: str
    stdout: str
    out: Path


def _run(row: Row, cwd: Path, out: Path, port: int) -> Result:
    env = dict(os.environ, OPENAI_API_KEY="", GHOSTSHELL_LLM_API_KEY="", ANTHROPIC_API_KEY="")
    for name in ("CAN_INTERFACE", "CAN_CHANNEL", "CAN_BITRATE", "CAN_CONFIG"):  # python-can's config: none
        env.pop(name, None)
    argv = [a.replace(OUT, str(out)).replace(TAKEN_PORT, str(port)) for a in row.argv]
    p = subprocess.run([sys.executable, "-m", "host", *argv], cwd=cwd, capture_output=True, text=True,
                       timeout=120, env=env, stdin=subprocess.DEVNULL)
    says = row.says.replace(TAKEN_PORT, str(port))
    return Result(Row(row.argv, says, row.status), p.returncode, p.stderr, p.stdout, out)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, str]]:
    root = tmp_path_factory.mktemp("exit_codes")
    return root, _files(root / "in")


@pytest.fixture(scope="module")
def results(inputs: tuple[Path, dict[str, str]]) -> list[Result]:
    root, files = inputs
    rows = _rows(files, OUT)
    with socket.socket() as taken, ThreadPoolExecutor(max_workers=4) as pool:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        return list(pool.map(lambda ir: _run(ir[1], root, root / "out" / str(ir[0]), port), enumerate(rows)))


def test_a_refused_out_file_is_left_as_it_was(inputs: tuple[Path, dict[str, str]], results: list[Result]) -> None:
    assert Path(inputs[1]["regular.txt"]).read_text(encoding="utf-8") == KEPT


#: usage errors that were found only after the board started, each truncating the folder's frame logs
LATE_USAGE_ERRORS = (
    ("run", "--task", "26", "--lockstep", "--no-live", "--mount-mcp", "head=x"),
    ("run", "--task", "26", "--lockstep", "--no-live", "--mount-mcp", "a=x", "--mount-mcp", "a=y"),
    ("run", "--task", "1", "--lockstep", "--no-live", "--link", "can:"),
    ("chat", "--replies", "{REPLIES}", "--lockstep", "--no-live", "--mount-mcp", "head=x"),
)


@pytest.mark.parametrize("argv", LATE_USAGE_ERRORS, ids=[" ".join(a) for a in LATE_USAGE_ERRORS])
def test_a_usage_error_leaves_the_previous_run_folder_alone(argv: tuple[str, ...], tmp_path: Path,
                                                            inputs: tuple[Path, dict[str, str]]) -> None:
    run = tmp_path / "previous"
    run.mkdir()
    kept = {"host_frames.jsonl": '{"previous": "run"}\n', "board_frames.jsonl": '{"previous": "run"}\n',
            "summary.json": "{}\n"}
    for name, text in kept.items():
        (run / name).write_text(text, encoding="utf-8")
    argv = tuple(a.replace("{REPLIES}", inputs[1]["replies2.txt"]) for a in argv)
    r = _run(Row((*argv, "--out", str(run)), ""), tmp_path, run, 0)
    assert r.status == 2, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert {p.name: p.read_text(encoding="utf-8") for p in run.iterdir()} == kept


def test_every_command_has_rows(results: list[Result]) -> None:
    covered = {r.row.argv[0] for r in results}
    assert covered >= set(COMMANDS), set(COMMANDS) - covered


def test_the_table_is_the_documented_one() -> None:
    assert sorted(EXIT_CODES) == [0, 1, 2, 130]
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    for status in EXIT_CODES:
        assert f"| {status} |" in readme, f"README's exit status table lacks {status}"


def _ids() -> list[str]:
    return [" ".join(r.argv)[:80] for r in _rows(_files_stub(), OUT)]


def _files_stub() -> dict[str, str]:
    return {k: k for k in ("empty.xml", "blank.xml", "latin1.xml", "prose.xml", "calls.xml", "garbage.log", "huge_line.log",
                           "garbage.jsonl", "empty.jsonl", "empty.log", "bad_skills.json", "folder", "replies2.txt",
                           "regular.txt", "missing")}


@pytest.mark.parametrize("index", range(len(_ids())), ids=_ids())
def test_bad_input_exits_with_its_status_and_one_line(index: int, results: list[Result]) -> None:
    r = results[index]
    row = r.row
    why = f"{' '.join(row.argv)}\n--- status {r.status}\n--- stderr:\n{r.stderr[-3000:]}\n--- stdout:\n{r.stdout[-1000:]}"
    assert r.status == row.status, why
    assert "Traceback" not in r.stderr and "Traceback" not in r.stdout, why
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert lines, why
    last = lines[-1]
    assert row.says in last, why
    assert len(lines) == 1, why  # exactly one line, naming the command (host.cli.OneLineParser)
    assert last.startswith(("ghostshell", "board: ")), why
    assert r.stdout == "", why  # nothing before the error: no banner, no board
    assert not r.out.exists(), why + "\n--- the refused command made its run folder"


def test_every_refusal_names_its_command(results: list[Result]) -> None:
    """One prefix rule (issue 45, item 4): a command's error line reads ``ghostshell COMMAND: ...``
    (:func:`host.commands.errors.print_error`), or ``ghostshell COMMAND ACTION: error: ...`` for
    argparse's usage error of a subcommand's action (``log decode``); never a bare ``ghostshell:``.
    ``ghostshell board`` is the board's own process (``python -m firmware_sim``): its refusals after
    argparse's read ``board: ...``, the form the host's board launcher reads (host.link.board_process)."""
    wrong = []
    for r in results:
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        command = r.row.argv[0]
        action = next((a for a in r.row.argv[1:] if not a.startswith("-")), "")
        prefixes = (f"ghostshell {command}: ", f"ghostshell {command} {action}: ", *(("board: ",) * (command == "board")))
        if not lines or not lines[-1].startswith(prefixes):
            wrong.append(f"{' '.join(r.row.argv)}: {lines[-1] if lines else '(no line)'}")
    assert not wrong, "\n".join(wrong)
