"""``python -m firmware_sim.wire_reference [--check]``: write ``docs/wire-protocol.md``: the tables of
:func:`protocol.wire_tables.render` (layouts, enumerations, CAN form) with the board's side: what each
message means, the refusals, the fault flags, the CONFIG keys, the two hashes' recipes, start-up,
board modes, the watchdog and the jitter buffer, with the numbers of the emulated board's defaults.
``--check`` exits 1 when the checked-in file differs.

The board's side is written here, next to the board it describes (``firmware_sim/board.py``; the C
firmware ``firmware_sim/c/core/gs_board.c`` behaves the same unless a sentence says otherwise), and
replaces the generic board section of :func:`protocol.wire_tables.render`. Its tables have the reference's
fixed shape (``| a | b |`` rows after a header and a ``| --- |`` row; a blank line ends a table), so a
program can read them (tests/cfirmware/test_reference_host.py does).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from firmware_sim.config import BoardConfig
from protocol import codec as c
from protocol import framing
from protocol.generated import check_or_write
from protocol.messages import BOARD_TO_HOST, PROTOCOL_VERSION, ConfigKey, MsgType
from protocol.wire_tables import BoardFacts
from protocol.wire_tables import render as render_tables

__all__ = ["CONFIG_RANGES", "DOC", "MEANING", "facts", "main", "render"]

DOC = Path(__file__).resolve().parents[1] / "docs" / "wire-protocol.md"
C_BUFFER_DEPTH = 32  # firmware_sim/c/core/gs_config.h GS_BUFFER_DEPTH
MAX_IMAGE_SIDE = 640  # firmware_sim/peripherals.py MAX_IMAGE_SIDE (imported there with MuJoCo; checked by a test)
I32_MAX = 2**31 - 1

#: what each message means, for the message table (a sentence, not the Python signature)
MEANING: dict[MsgType, str] = {
    MsgType.HELLO: "First message of a session (optional, recommended): the host's protocol version and schema hash. "
                   "Answer: CAPS, or NACK VERSION_MISMATCH / SCHEMA_MISMATCH.",
    MsgType.CAPS: "The answer to HELLO: protocol version, schema hash, the robot's name, servo count and "
                  "`servo_table_hash`, control rate, jitter-buffer depth (frames), telemetry rate, board time and "
                  "whether the board runs in lockstep. A host refuses a board whose robot, servo count or servo table "
                  "hash differ from the robot it drives.",
    MsgType.TIME_SYNC_REQUEST: "NTP-style clock probe: `t1_host_us` is the host clock at send. Answer: TIME_SYNC_REPLY.",
    MsgType.TIME_SYNC_REPLY: "`t1_host_us` sent back with `t2_board_us` (board clock at receipt) and `t3_board_us` "
                             "(board clock at send).",
    MsgType.CONFIG: "Set one board parameter: `key` (ConfigKey) to `value` (i32; unit and range per key in "
                    "[CONFIG keys](#config-keys)), from now until the board restarts. Answer: ACK, or NACK BAD_VALUE "
                    "(unknown key or value out of range; nothing changes).",
    MsgType.HEARTBEAT: "Feeds the board's watchdog when the host has nothing else to send; no answer. "
                       "`sender_time_us`: the sender's clock (informational). The boards never send one.",
    MsgType.ADVANCE: "Lockstep only: let the board clock run up to `until_us` (µs of board time). Answer: ACK "
                     "(a realtime board: NACK NOT_LOCKSTEP).",
    MsgType.SERVO_FRAME: "Targets (rad) for the masked servos to reach at `apply_at_us` on the board clock; the board "
                         "interpolates between frames. No answer when accepted (telemetry's `last_applied_seq` "
                         "confirms it), NACK with the reason when refused.",
    MsgType.FLUSH: "Drop the buffered targets due at or after `from_us` for the masked servos (those servos continue "
                   "from their present command). Answer: ACK.",
    MsgType.ESTOP: "Emergency stop: empties the jitter buffer, holds every servo where it is from the next tick and "
                   "refuses frames (NACK ESTOPPED) until ESTOP_CLEAR. Answer: ACK (also when already stopped).",
    MsgType.ESTOP_CLEAR: "Releases ESTOP, a latched WATCHDOG_FAULT and a latched SERVO_FAULT; the servos continue from "
                         "where they are into the next frames. Answer: ACK (also when nothing was latched).",
    MsgType.TELEMETRY: "The board's state after the tick that ends at `board_time_us`, at the telemetry rate: measured "
                       "position (rad), velocity (rad/s) and effort (N*m) per servo, IMU roll/pitch/yaw (rad), fault "
                       "flags, frames in the jitter buffer, the sequence number of the last applied SERVO_FRAME, and "
                       "counters since boot (late frames, other refused frames, link errors).",
    MsgType.SIM_STATE: "Emulator only, after each TELEMETRY: ground truth of the floating base (position m, "
                       "quaternion w x y z), scene objects and how many toppled. No real board sends it.",
    MsgType.ACK: "The message with sequence number `ack_seq` and type `msg_type` was accepted and has taken effect.",
    MsgType.NACK: "The message with sequence number `ack_seq` and type `msg_type` was refused for `reason` "
                  "(NackReason) and changed nothing; `detail` says why (ASCII, may be empty). An unsolicited "
                  "NACK SERVO_FAULT (msg_type SERVO_FRAME, `ack_seq` the last sequence number received) reports a "
                  "failed servo.",
    MsgType.SCREEN: "Show an expression or animation from `start_at_us` for `duration_ms` (0 = until replaced). "
                    "Answer: ACK.",
    MsgType.SPEAKER: "Play or stop speech or a clip from `start_at_us` on the board clock. Answer: ACK.",
    MsgType.CAMERA_CAPTURE: f"Ask the head camera for one `width` x `height` image (1..{MAX_IMAGE_SIDE} each). "
                            "Answer: CAMERA_CHUNKs (the same `request_id` again: the same image), or NACK NO_RENDERER "
                            "(always on the C firmware), BUSY or BAD_VALUE.",
    MsgType.CAMERA_CHUNK: "One piece of an encoded image (PNG); `index` counts from 0 to `total - 1`.",
    MsgType.CAMERA_RESEND: "Send chunks of one of the last two images again: bit k of `wanted` (byte k // 8, bit "
                           "k % 8) asks for chunk `first + k`; an empty `wanted` asks for all. Answer: those chunks, "
                           "or NACK BAD_VALUE when the image is no longer kept.",
}

#: ConfigKey -> (unit, lowest accepted, highest accepted or None for the control rate, what it sets)
CONFIG_RANGES: dict[ConfigKey, tuple[str, int, int | None, str]] = {
    ConfigKey.TELEMETRY_RATE_HZ: ("Hz", 1, None, "TELEMETRY (and SIM_STATE) every `round(control_rate / value)` ticks"),
    ConfigKey.WATCHDOG_MS: ("ms", 1, I32_MAX, "link silence before the board holds (WATCHDOG_HOLD)"),
    ConfigKey.MAX_LATE_US: ("µs", 0, I32_MAX, "a SERVO_FRAME due more than this before the board clock is NACKed LATE"),
    ConfigKey.MAX_FUTURE_US: ("µs", 1, I32_MAX,
                              "a SERVO_FRAME due more than this after the board clock is NACKed TOO_FAR_FUTURE"),
    ConfigKey.CROUCH_AFTER_MS: ("ms", 0, I32_MAX, "time in the hold before the safe pose and WATCHDOG_FAULT"),
}


def facts() -> BoardFacts:
    import firmware_sim.board as board

    cfg = BoardConfig()
    doc = board.__doc__ or ""
    policy = doc[doc.index("Reply policy:"):].split("\n\n")[0].strip() if "Reply policy:" in doc else ""
    policy = policy.replace("``KEPT_IMAGES``", str(board.KEPT_IMAGES)).replace("``", "`")  # reST -> Markdown
    return BoardFacts(rate_hz=cfg.rate_hz, telemetry_rate_hz=cfg.telemetry_rate_hz, watchdog_ms=cfg.watchdog_ms,
                      crouch_after_ms=cfg.crouch_after_ms, max_late_us=cfg.max_late_us,
                      max_future_us=cfg.max_future_us, buffer_depth=cfg.buffer_depth, c_buffer_depth=C_BUFFER_DEPTH,
                      reply_policy=policy)


def _replace(text: str, old: str, new: str) -> str:
    """``text`` with its one ``old`` replaced (ValueError when the generic page no longer has it)."""
    if text.count(old) != 1:
        raise ValueError(f"protocol.wire_tables.render changed: {old[:60]!r} found {text.count(old)} times")
    return text.replace(old, new)


def _message_table(text: str) -> str:
    lines = text.split("\n")
    start = lines.index("## Message types") + 4
    end = lines.index("", start)
    for k in range(start, end):
        code, name, direction, _ = (x.strip() for x in lines[k].strip("|").split("|"))
        t = MsgType[name]
        if t is MsgType.HEARTBEAT:
            direction = "host → board"
        assert ("board → host" if t in BOARD_TO_HOST else "host → board") == direction, t
        lines[k] = f"| {code} | {name} | {direction} | {MEANING[t]} |"
    return "\n".join(lines)


def _hashes(cfg: BoardConfig) -> list[str]:
    return [
        "## Hashes",
        "",
        "Both are a u32: the first four bytes, read big-endian, of the SHA-256 digest of a UTF-8 text with `\\n` line "
        "ends (no `\\r`), the last line ended by `\\n` too. In Python: "
        "`int.from_bytes(hashlib.sha256(text.encode()).digest()[:4], \"big\")`.",
        "",
        "- **`schema_hash`** (HELLO, CAPS): the text is the lines of the *schema text* block above, exactly as shown "
        "(two spaces before each field line, no trailing spaces), joined with `\\n`, plus one `\\n` after the last "
        f"line. For the tables above it gives `{c.SCHEMA_HASH:#010x}`; the u32-mask schema's text (first line "
        f"`protocol {PROTOCOL_VERSION} max_servos {c.WIRE_SCHEMA_32.max_servos} max_payload {c.MAX_PAYLOAD}`, every "
        f"`mask16` a `mask32`) gives `{c.WIRE_SCHEMA_32.hash:#010x}`.",
        "- **`servo_table_hash`** (CAPS): the text is built from the robot's `robots/<name>/servos.toml`:",
        "  1. `servos N` (N: the number of servos);",
        "  2. one line per servo in ascending `id`: `id name joint actuator neutral min max direction max_speed`, one "
        "space between fields; `name`, `joint`, `actuator` as written in the table (`actuator` defaults to "
        "`joint`); `direction` the integer (`1` or `-1`, default `1`); `neutral`, `min`, `max` = `neutral_deg`, "
        "`min_deg`, "
        "`max_deg` in radians and `max_speed` = `max_speed_dps` in rad/s (defaults: `neutral_deg` 0, "
        "`max_speed_dps` 300);",
        "  3. `model resolution deadband`: `[model]` `resolution_deg` and `deadband_deg` in radians (defaults 0.088 "
        "and 0.2).",
        "",
        "  Degrees become radians as `x * (pi / 180)` in IEEE-754 double precision (Python's `math.radians`); every "
        "real number is printed with C's `%.9g` (Python `f\"{x:.9g}\"`: 9 significant digits, no trailing zeros, "
        "`0` for zero, `-0` for negative zero). CoCo's first lines: `servos 12`, "
        "`1 fr_hip fr_hip fr_hip 0 -1.04719755 1.04719755 1 6.98131701`; its last: "
        "`model 0.00153588974 0.0034906585`. `ghostshell robots show NAME` prints a robot's table.",
        "",
    ]


def _refusals(f: BoardFacts) -> list[str]:
    silent = ("dropped without an answer; `link_errors` + 1 and LINK_ERRORS in the next TELEMETRY; does not feed the "
              "watchdog")
    fix = "fix the sender: the board will never accept these bytes"
    rows = [
        ("bytes between two `0x00` that are not valid COBS, or fewer than 7 bytes after decoding", silent,
         "resend what needed an answer when its answer times out; a rising `link_errors` means a bad line"),
        ("a CRC mismatch", silent, "as above (line noise)"),
        (f"more than {framing.DEFAULT_MAX_FRAME_BYTES} bytes without a `0x00`",
         "discarded up to the next `0x00`, counted once as a link error", "end every frame with `0x00`"),
        (f"header `version` other than {PROTOCOL_VERSION}", silent, "speak protocol version 1"),
        ("`length` different from the payload bytes in the frame", silent, fix),
        ("an unknown message type", silent, fix),
        ("a payload that does not decode: shorter than its layout, bytes after the payload, a SERVO_FRAME target "
         "-32768 or a count of targets other than the mask's bits, a `bool` other than 0/1, an unknown enum value "
         "(other than a CONFIG key), a mask bit above the schema's servos, a string that is not UTF-8 or longer than "
         "its maximum", silent, fix),
        ("CONFIG with an unknown key (frame and payload length otherwise valid)",
         "NACK BAD_VALUE (msg_type CONFIG); nothing changes", "do not use that key with this board"),
        ("CONFIG with a value out of the key's range ([CONFIG keys](#config-keys))", "NACK BAD_VALUE; nothing changes",
         "send a value in range"),
        (f"HELLO whose `protocol_version` is not {PROTOCOL_VERSION}", "NACK VERSION_MISMATCH",
         "stop: the board speaks another protocol"),
        ("HELLO whose `schema_hash` is not the board's", "NACK SCHEMA_MISMATCH (`detail` names both hashes)",
         "stop, or use the board's schema (robots of 17..32 servos: the u32-mask schema)"),
        ("a robot the host did not expect (CAPS `robot`, `servo_count` or `servo_table_hash` differ)",
         "nothing: the board does not check; it answered HELLO with CAPS", "stop before sending frames"),
        ("SERVO_FRAME with mask 0 or a bit at or above the robot's servo count", "NACK BAD_VALUE; `dropped_count` + 1",
         "mask only servos 1..servo_count (CAPS)"),
        ("SERVO_FRAME during ESTOP", "NACK ESTOPPED; `dropped_count` + 1",
         "send ESTOP_CLEAR when it is safe, then new frames"),
        ("SERVO_FRAME with WATCHDOG_FAULT latched", "NACK FAULT_LATCHED; `dropped_count` + 1",
         "ESTOP_CLEAR, then new frames; keep the link fed (HEARTBEAT)"),
        ("SERVO_FRAME with SERVO_FAULT latched (a real servo bus)", "NACK SERVO_FAULT naming the servo; "
         "`dropped_count` + 1", "fix the servo; ESTOP_CLEAR tries again"),
        (f"SERVO_FRAME due more than {f.max_late_us} µs before the board clock", "NACK LATE; `late_count` + 1",
         "send frames further ahead; check the clock offset (TIME_SYNC)"),
        (f"SERVO_FRAME due more than {f.max_future_us} µs after the board clock", "NACK TOO_FAR_FUTURE; "
         "`dropped_count` + 1", "check the clock offset; do not plan further ahead"),
        ("SERVO_FRAME with the jitter buffer full", "NACK BUFFER_FULL; `dropped_count` + 1",
         "keep fewer frames ahead than CAPS `buffer_depth`"),
        ("ADVANCE to a realtime board", "NACK NOT_LOCKSTEP", "do not send ADVANCE unless CAPS `lockstep` is 1"),
        ("a message only the board sends (" + ", ".join(t.name for t in sorted(BOARD_TO_HOST)) + ")",
         "NACK UNSUPPORTED with that msg_type; does not feed the watchdog", fix),
        (f"CAMERA_CAPTURE with a side outside 1..{MAX_IMAGE_SIDE}; CAMERA_RESEND of an image no longer kept",
         "NACK BAD_VALUE", "ask for a smaller image; capture again"),
        ("CAMERA_CAPTURE on a board without a renderer (the C firmware, a headless emulator) or with too many in "
         "flight", "NACK NO_RENDERER, NACK BUSY", "do without images; retry later"),
    ]
    out = [
        "## Refusals",
        "",
        "Every message the board receives is answered by this table's second column or by the reply policy below. A "
        "NACK's `ack_seq` is the refused message's sequence number and `msg_type` its type; a refused message changes "
        "nothing but the counter named (it still feeds the watchdog, as every well-formed message from the host "
        "does). \"Silent\" rows: the board drops the bytes and answers nothing, because "
        "it cannot trust their type or sequence number (a CRC error is line noise as often as a bug), and counts them: "
        "`link_errors` in TELEMETRY (since boot, never reset) and the LINK_ERRORS flag in the next report.",
        "",
        "| what arrives | what the board does | what the host should do |",
        "| --- | --- | --- |",
    ]
    out += [f"| {a} | {b} | {h} |" for a, b, h in rows]
    out += [
        "",
        "Why a CONFIG with an unknown key gets a NACK although the codec cannot decode it: its frame checks (COBS, "
        "CRC, version, length, type) and its payload has CONFIG's 5 bytes, so it is a message the host meant to send "
        "and is waiting to see acknowledged; silence would leave that host waiting until its timeout without a "
        "reason. The code is BAD_VALUE, as for a value out of range (the key byte is a bad value of a message the "
        "board accepts; UNSUPPORTED means the board does not accept the message type at all). Both boards answer it "
        "on a serial link; over CAN a CONFIG travels as an ISO-TP unit whose decode failure is still a silent link "
        "error.",
        "",
        "The order of a SERVO_FRAME's checks: mask, ESTOP, latched watchdog fault, servo fault, LATE, TOO_FAR_FUTURE, "
        "BUFFER_FULL (the first that fails answers).",
        "",
    ]
    return out


def _fault_flags(f: BoardFacts) -> list[str]:
    rows = [
        ("ESTOP", "an ESTOP was received", "ESTOP_CLEAR", "level"),
        ("WATCHDOG_HOLD", f"the first tick more than {f.watchdog_ms} ms of board time after the last valid message "
         "(an armed watchdog, no ESTOP): the buffer is emptied and every servo holds its command",
         "the next valid message (the board resumes), the latch below, or ESTOP_CLEAR", "level"),
        ("WATCHDOG_FAULT", f"{f.crouch_after_ms} ms after the hold began: the servos move to the robot's safe pose "
         "and frames are refused (FAULT_LATCHED)", "ESTOP_CLEAR only", "level, latched"),
        ("CLAMPED", "a tick since the previous report (the board running frames) clamped a target to the servo "
         "table's range or speed", "by that report", "since the last report"),
        ("TICK_OVERRUN", "a realtime tick since the previous report started more than one period late (never in "
         "lockstep)", "by that report", "since the last report"),
        ("LINK_ERRORS", "a frame since the previous report was dropped as undecodable", "by that report: watch the "
         "`link_errors` counter, which only grows", "since the last report"),
        ("SERVO_FAULT", "a servo on a real servo bus stopped answering or reported an error (an unsolicited NACK "
         "SERVO_FAULT names it); every servo holds, frames are refused", "ESTOP_CLEAR (a servo still failing latches "
         "it again)", "level, latched"),
    ]
    out = [
        "## Fault flags",
        "",
        "TELEMETRY `faults` (bits in the FaultFlags table above). A *level* flag is set in every report while the "
        "condition lasts. A *since the last report* flag is set in a report when its event happened at least once "
        "since the previous report, and that report clears it: a host that misses the report misses the flag (an "
        "error that goes on sets it in every report). For LINK_ERRORS watch the `link_errors` counter instead; "
        "CLAMPED and TICK_OVERRUN have no counter on the wire.",
        "",
        "| flag | set when | cleared | kind |",
        "| --- | --- | --- | --- |",
    ]
    out += [f"| {a} | {b} | {cl} | {k} |" for a, b, cl, k in rows]
    return out + [""]


def _config_keys(f: BoardFacts) -> list[str]:
    cfg = BoardConfig()
    default = {ConfigKey.TELEMETRY_RATE_HZ: cfg.telemetry_rate_hz, ConfigKey.WATCHDOG_MS: cfg.watchdog_ms,
               ConfigKey.MAX_LATE_US: cfg.max_late_us, ConfigKey.MAX_FUTURE_US: cfg.max_future_us,
               ConfigKey.CROUCH_AFTER_MS: cfg.crouch_after_ms}
    out = [
        "## CONFIG keys",
        "",
        "`value` is an i32; a value outside `min`..`max` is refused (NACK BAD_VALUE), as is a key not listed. The "
        "setting lasts until the board restarts (a HELLO does not reset it); CAPS reports the telemetry rate in "
        f"force. `max` of TELEMETRY_RATE_HZ is the control rate ({f.rate_hz} Hz, CAPS `control_rate_hz`).",
        "",
        "| value | key | unit | min | max | default | sets |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    for k, (unit, lo, hi, what) in CONFIG_RANGES.items():
        out.append(f"| {int(k)} | {k.name} | {unit} | {lo} | {hi if hi is not None else f.rate_hz} | {default[k]} | "
                   f"{what} |")
    return out + [""]


def _behaviour(f: BoardFacts) -> list[str]:
    tick_ms = 1000 / f.rate_hz
    hold_at = f.watchdog_ms + tick_ms
    return [
        "## Board behaviour a client must know",
        "",
        "### Start-up",
        "",
        "- The board starts at board time 0 with every servo commanded to the neutral pose (the servo table's "
        "`neutral_deg`; the emulated robot standing on the floor), the jitter buffer empty, every counter 0, "
        "`last_applied_seq` 0 until a frame has been applied (number frames from 1, or start anywhere but 0, to tell "
        "\"none applied yet\" from frame 0), no fault flag, and the watchdog unarmed: the first valid message arms "
        "it.",
        "- A **realtime** board ticks from power-up and sends TELEMETRY (then SIM_STATE, emulator only) at the "
        "telemetry rate whether or not a host listens; a host that opens the port may first read reports queued "
        "before it came (their `board_time_us` shows their age). A **lockstep** board runs no tick, so sends no "
        "report, until the host's first ADVANCE or SERVO_FRAME.",
        "- **HELLO is optional** for the board (it handles every message without one) but a host should send it: "
        f"CAPS tells the schema, robot, servo count, control rate ({f.rate_hz} Hz), jitter-buffer depth (frames; "
        f"{f.buffer_depth} on the Python board, {f.c_buffer_depth} on the C firmware), telemetry rate, board time and "
        "whether the board runs in lockstep. A HELLO with sequence number 0 also restarts the board's count of lost "
        "sequence numbers.",
        "- The board never sends HEARTBEAT (the CAN form's HEARTBEAT_BOARD code is unused by both boards): a host "
        f"knows the board is alive from TELEMETRY ({f.telemetry_rate_hz} Hz by default).",
        "- Sequence numbers: one u16 counter per direction; the board numbers what it sends from 0 at start-up; the "
        "host may start anywhere.",
        "- **Two version fields**, both 1 today: the frame header's `version` (byte 0 of every frame; another value: "
        f"the frame is dropped silently as a link error) and `protocol_version` in HELLO and CAPS (HELLO with another "
        "value: NACK VERSION_MISMATCH, because that frame itself is readable). A host sends both as "
        f"{PROTOCOL_VERSION} and refuses a CAPS whose `protocol_version` or `schema_hash` differ from its own.",
        "",
        "### Realtime or lockstep",
        "",
        "- A **realtime** board (the default, and the only kind of real board) runs its clock at wall time: the host "
        "estimates the clock offset with TIME_SYNC and sends frames due a little ahead of the board clock (within the "
        f"SERVO_FRAME window below). An outside host that drives a robot, real or emulated, should be written for "
        "this mode, and use lockstep only for reproducible tests.",
        "- A **lockstep** board (`ghostshell board --lockstep`, emulator only, CAPS `lockstep` = 1) lets its clock "
        "run only as far as the host allows: it starts at board time 0 and runs a tick at time `t` only while a "
        "received SERVO_FRAME is due at or after `t`, or `t < until_us` of an ADVANCE. It handles the next message "
        "only when it cannot tick, so a run is a function of the host's byte stream alone: for tests, batch "
        "simulation and replays, not for timing. ADVANCE to a realtime board is NACKed NOT_LOCKSTEP.",
        f"- **The lockstep trap**: the watchdog runs on board time. A message feeds it at the board time at which it "
        f"is handled (where the board stopped), an applied frame at its apply time. An ADVANCE that spans more than "
        f"{f.watchdog_ms} ms with no frame applied in it trips the watchdog: ADVANCE to 1 s handled at board time 0 "
        f"holds from the tick at {hold_at / 1000:.3f} s (the first tick more than {f.watchdog_ms} ms after the last "
        f"valid message; ticks are {tick_ms:g} ms apart), with WATCHDOG_HOLD in the reports from then on, and "
        f"latches WATCHDOG_FAULT {f.crouch_after_ms} ms later. A HEARTBEAT cannot prevent it (the board reads it only "
        f"after the ADVANCE is used up). So a lockstep host sends ADVANCE in steps of at most {f.watchdog_ms} ms "
        f"whenever no frame is due in the span (each step's `until_us` at most {f.watchdog_ms} ms past the previous "
        f"one's), or keeps frames due at least every {f.watchdog_ms} ms; or raises the watchdog with CONFIG "
        "WATCHDOG_MS.",
        "",
        "### Telemetry",
        "",
        f"- TELEMETRY (then SIM_STATE, emulator only) every `round({f.rate_hz} / telemetry_rate)` ticks "
        f"({f.telemetry_rate_hz} Hz by default), stamped with the board time after that tick. `last_applied_seq` is "
        "the sequence number of the last SERVO_FRAME applied: it confirms frames (accepted frames get no ACK). "
        "`late_count` counts frames NACKed LATE, `dropped_count` the other refused frames, `link_errors` undecodable "
        "frames, all since boot.",
        "",
        "### Frames, interpolation and the jitter buffer",
        "",
        f"- **SERVO_FRAME window**: a frame due more than {f.max_late_us} µs before the board clock is NACKed LATE, "
        f"more than {f.max_future_us} µs after it TOO_FAR_FUTURE, a full buffer BUFFER_FULL. `apply_at_us` is the "
        "board clock modulo 2**32; the board unwraps it to the time nearest its clock. Frames with the same apply "
        "time: the later one wins for the servos both cover.",
        "- **Interpolation**: each servo moves linearly from its last applied keyframe (that frame's apply time and "
        "target) to its next buffered one, and stays at its last target when nothing is buffered for it; the servo "
        "model then clamps to the table's range and speed (CLAMPED). **A sparse keyframe starts from its arrival**: "
        f"a frame for a servo with nothing buffered whose last keyframe is more than {BoardConfig().resume_gap_us // 1000} "
        "ms old starts that servo's segment at the frame's arrival (board time when handled), from where the servo "
        "is commanded then, not from the old keyframe's time. So a host sending one keyframe per move sets "
        "`apply_at_us` to arrival + the move's duration; a stream of frames closer together interpolates keyframe to "
        "keyframe.",
        "- **ESTOP empties the jitter buffer**: every accepted frame not yet applied is dropped, also frames due after "
        "a later ESTOP_CLEAR, which are never applied. After ESTOP_CLEAR the host sends new frames. ESTOP takes "
        "effect at the next tick and holds where the servos are (`--estop-torque limp` on a real servo bus: torque "
        "off); frames are NACKed ESTOPPED until ESTOP_CLEAR. A watchdog hold empties the buffer too when it begins.",
        f"- **Leaving a hold** (a valid message after WATCHDOG_HOLD, or ESTOP_CLEAR): each servo waits at its held "
        f"command until its first new keyframe, then blends into the stream (minimum-jerk, peak "
        f"{BoardConfig().resume_speed:g} rad/s, at least {BoardConfig().resume_blend_min_us // 1000} ms).",
        "",
        "### Watchdog",
        "",
        f"- Armed by the first valid message. After {f.watchdog_ms} ms of board time without a valid message the board "
        f"HOLDs (WATCHDOG_HOLD; the next valid message resumes); {f.crouch_after_ms} ms later it moves to the robot's "
        "safe pose and latches WATCHDOG_FAULT, refusing frames (NACK FAULT_LATCHED) until ESTOP_CLEAR. A realtime "
        "host sends HEARTBEAT when it has nothing else to send (the Python host: after 50 ms of silence; on a slow "
        "line, after half the watchdog it set). In lockstep, applied frames feed it too (see the lockstep trap).",
        f"- **A slow line**: every valid message feeds the watchdog (both boards), so it must only be longer than the "
        f"longest gap between the host's messages. A host whose frames come further apart than a third of "
        f"{f.watchdog_ms} ms (a serial line too slow for 100 frames/s: a 12-servo frame is 162 ms of wire at 2 400 "
        "baud) raises it with CONFIG WATCHDOG_MS right after CAPS, before TIME_SYNC, on every connect (the setting "
        "lasts until the board restarts; a board that NACKs it cannot be used on that line). The Python host asks for "
        "three of its frame periods (the life time factor of CANopen node guarding: one lost frame and a period of "
        "jitter do not trip it, a dead line does within three periods), and at least one frame period more than "
        "the report period (a lockstep host ADVANCEs a board that went quiet one report period with no frame in "
        "it); it lowers TELEMETRY_RATE_HZ to what fills half the line (at least 1 Hz), sends frames with only the "
        "servos that move, and refuses (before it starts) a line too slow for 1 Hz reports. CoCo at 2 400 baud: a "
        "frame every 210 ms, WATCHDOG_MS 1220, TELEMETRY_RATE_HZ 1; at 1 200 baud: refused.",
        "- **TIME_SYNC**: the host sends `t1_host_us` (its clock at send); the reply carries it back with "
        "`t2_board_us` (board clock at receive) and `t3_board_us` (board clock at send). With `t4` the host clock at "
        "receipt: offset = ((t2 - t1) + (t3 - t4)) / 2, round trip = (t4 - t1) - (t3 - t2) (NTP).",
        "- **Servo bus faults** (a real servo bus: the C firmware, or the Python board with `--servo-bus`): a servo "
        "that stops answering latches SERVO_FAULT in telemetry, one NACK SERVO_FAULT (msg_type SERVO_FRAME) names it, "
        "every servo holds and frames are refused until ESTOP_CLEAR.",
        "- **Camera**: the C firmware has no renderer and NACKs CAMERA_CAPTURE with NO_RENDERER.",
        "",
    ]


def render() -> str:
    """The whole reference as Markdown: :func:`protocol.wire_tables.render` with the board's side."""
    f = facts()
    text = render_tables(f)
    text = _message_table(text)
    text = _replace(text, "schema text below (UTF-8). ", "schema text below (recipe: [Hashes](#hashes)). ")
    text = _replace(text, "`servo_table_hash` (first four bytes of SHA-256 over the table's canonical text)",
                    "`servo_table_hash` ([Hashes](#hashes))")
    text = _replace(text, "Reply policy (the Python board's, `firmware_sim/board.py`):",
                    "Reply policy (both boards; the C firmware answers every CAMERA_CAPTURE with NO_RENDERER):")
    head, rest = text.split("## Board behaviour a client must know\n", 1)
    policy = rest[rest.index("Reply policy (both boards"):rest.index("## CAN form")]
    board = _behaviour(f) + _refusals(f) + _fault_flags(f) + _config_keys(f) + _hashes(BoardConfig())
    return head + "\n".join(board) + "\n" + policy + rest[rest.index("## CAN form"):]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m firmware_sim.wire_reference", description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=DOC)
    p.add_argument("--check", action="store_true", help="exit 1 when the page differs from the generated text")
    args = p.parse_args(argv)
    return check_or_write({args.out: render()}, check=args.check, command="python -m firmware_sim.wire_reference")


if __name__ == "__main__":
    sys.exit(main())
