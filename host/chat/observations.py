"""The observation message: what one executed reply did, as the next user-side chat message.

Format (plain text; one line per item, every line bounded, at most
:data:`MAX_LINES` call lines)::

    <observations step="2/4" board_time_s="12.34">
    calls:
    - done head_act(action='nod', duration=2.0) [head_act[0]] -> nodded
    - failed wave(times=99) [wave[0]]: <wave> times=99 is out of range [1, 10]
    - interrupted move_strides(direction='forward', times=6) [head_act[0]/move_strides[0]]
    - cancelled wave() [wave[1]] (never started)
    warnings:
    - parse warning at 17: ...
    notes:
    - skill 'greet' saved
    robot: upright, max tilt 3.1 deg; base moved 0.12 m (from x=0.00 y=0.00 yaw=0 to x=0.12 y=0.01 yaw=2 deg)
    events:
    - fall at board time 3.20 s: the robot fell over (tilt 80 deg, ...); motion was stopped
    interrupted: the user interrupted this turn; only what ran before the cut is kept above
    camera: 1 photo attached
    </observations>

``step`` is the ReAct step within the user turn. The message is data for the
model, never input to the shell: the shell only parses assistant replies, so
function tokens quoted inside an observation (e.g. in an error message) are never
executed. Camera captures become OpenAI-style image parts
(``{"type": "image_url", "image_url": {"url": "data:image/png;base64,..."}}``)
when the model takes images; otherwise the text names the photo files.
"""

from __future__ import annotations

import base64
import math
from pathlib import Path
from typing import Any

from host.run.robot_session import TurnResult

#: most call lines in one observation message (the rest are counted, not listed)
MAX_LINES = 40
#: longest single line (characters)
MAX_LINE = 300

TAG = "observations"


def _clip(text: str, n: int = MAX_LINE) -> str:
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[: n - 1] + "…"


def _call(function: str, args: dict[str, Any]) -> str:
    shown = {k: v for k, v in args.items()}
    return f"{function}({', '.join(f'{k}={v!r}' for k, v in shown.items())})"


def telemetry_line(turn: TurnResult) -> str:
    """``robot: upright|FELL, max tilt D deg; base moved M m (from ... to ...)``; ``robot: pose unknown ...``
    when no SIM_STATE report reached the host (a line too slow for them): not a robot that stood still."""
    s = turn.summary
    if s.extra.get("base_reports") == 0 or s.base_start is None or s.base_end is None or s.max_tilt_deg is None:
        return "robot: pose unknown (no SIM_STATE report reached the host)"
    (x0, y0, w0), (x1, y1, w1) = s.base_start, s.base_end
    moved = math.hypot(x1 - x0, y1 - y0)
    x0, y0, x1, y1 = (round(v, 2) + 0.0 for v in (x0, y0, x1, y1))  # no "-0.00"
    state = "FELL OVER" if s.fell else "upright"
    return (f"robot: {state}, max tilt {s.max_tilt_deg:.1f} deg; base moved {moved:.2f} m "
            f"(from x={x0:.2f} y={y0:.2f} yaw={round(w0)} to x={x1:.2f} y={y1:.2f} yaw={round(w1)} deg)")


def observation_text(turn: TurnResult, *, step: int, max_steps: int, images_attached: int = 0) -> str:
    """The text of the observation message for ``turn`` (see the module docstring)."""
    res = turn.result
    lines = [f'<{TAG} step="{step}/{max_steps}" board_time_s="{turn.board_t0 + turn.summary.duration_s:.2f}">']
    calls = [r for r in res.timeline if r.function not in ("wait", "async")]
    if calls:
        lines.append("calls:")
    for r in calls[:MAX_LINES]:
        head = f"- {r.outcome} {_call(r.function, r.args)} [{r.path}]"
        if r.outcome == "failed" and r.error:
            head += f": {r.error}"
        elif r.start is None and r.outcome in ("cancelled", "interrupted"):
            head += " (never started)"
        elif r.result is not None:
            head += f" -> {r.result}"
        lines.append(_clip(head))
    if len(calls) > MAX_LINES:
        lines.append(f"- ... and {len(calls) - MAX_LINES} more calls")
    warnings = [o for o in res.observations if o.kind == "warning"]
    notes = [o for o in res.observations if (o.kind == "info" and not o.message.startswith("event: "))
             or (o.kind == "error" and o.path is None)]
    for title, items in (("warnings:", warnings), ("notes:", notes)):
        if items:
            lines.append(title)
            lines.extend(_clip(f"- {o.message}") for o in items[:MAX_LINES])
    if turn.events:
        lines.append("events:")
        lines.extend(_clip(f"- {e}") for e in turn.events[:MAX_LINES])
    lines.append(telemetry_line(turn))
    if res.interrupted and turn.interrupted_by is not None:
        lines.append(_clip(f"interrupted: by the event above ({turn.interrupted_by.kind}); only what ran before "
                           "the cut is kept above"))
    elif res.interrupted:
        lines.append("interrupted: the user interrupted this turn; only what ran before the cut is kept above")
    captures = [Path(p) for p in turn.summary.extra.get("captures", [])]
    if captures:
        how = "attached" if images_attached else "saved as " + ", ".join(p.name for p in captures)
        lines.append(f"camera: {len(captures)} photo{'s' if len(captures) > 1 else ''} {how}")
    lines.append(f"</{TAG}>")
    return "\n".join(lines)


def observation_message(turn: TurnResult, *, step: int, max_steps: int, vision: bool) -> dict[str, Any]:
    """The user-side chat message for ``turn``: text, plus image parts for a vision model."""
    photos = [turn.out / name for name in turn.summary.extra.get("captures", [])]
    photos = [p for p in photos if p.exists()]
    attach = photos if vision else []
    text = observation_text(turn, step=step, max_steps=max_steps, images_attached=len(attach))
    if not attach:
        return {"role": "user", "content": text}
    parts: list[dict[str, Any]] = [{"type": "text", "text": text}]
    for p in attach:
        data = base64.b64encode(p.read_bytes()).decode("ascii")
        parts.append({"type": "image_url", "image_url": {"url": f"data:image/png;base64,{data}"}})
    return {"role": "user", "content": parts}
