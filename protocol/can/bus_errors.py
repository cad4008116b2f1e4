"""One clear line for a CAN bus that python-can could not open (shared by host and board; pure text).

``describe_bus_open_error(spec, exc)`` turns what ``can.Bus(**spec.bus_kwargs())`` raised (python-can's
``CanInterfaceNotImplementedError`` / ``CanInitializationError`` / ``CanOperationError``, an
``OSError`` from the kernel or pyserial, a ``ValueError``/``TypeError``/``struct.error`` from an
interface class refusing an argument) into ``"cannot open CAN bus SPEC: PROBLEM; WHAT TO DO"``.
The caller keeps ``exc`` as the cause (``raise ... from exc``). python-can is not imported here
(``protocol/`` stays free of I/O libraries): its exceptions are recognised by class name, which is
python-can's public API (``can.exceptions``), and OS errors by ``errno`` (on the exception, its
python-can ``error_code``, or its cause/context: pyserial wraps termios errors).
"""

from __future__ import annotations

import errno
from collections.abc import Collection

from protocol.linkspec import LinkSpec

__all__ = ["describe_bus_open_error"]


def _errno(exc: BaseException) -> int | None:
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        for code in (getattr(e, "errno", None), getattr(e, "error_code", None)):
            if isinstance(code, int) and code > 0:
                return code
        if isinstance(e, OSError) and e.args and isinstance(e.args[0], int):
            return int(e.args[0])
        if type(e).__name__ == "error" and e.args and isinstance(e.args[0], int):  # termios.error(25, ...)
            return int(e.args[0])
        e = e.__cause__ or e.__context__
    return None


def _class_names(exc: BaseException) -> set[str]:
    return {c.__name__ for c in type(exc).__mro__}


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return (text[0] if text else type(exc).__name__).rstrip(".")


def describe_bus_open_error(spec: LinkSpec, exc: BaseException, *, interfaces: Collection[str] = ()) -> str:
    """``"cannot open CAN bus SPEC: PROBLEM; WHAT TO DO"`` (one line) for ``exc`` raised opening ``spec``.

    ``interfaces``: python-can's interface names (``can.VALID_INTERFACES``), listed when the spec
    names an unknown one.
    """
    iface = spec.interface or "(configured)"
    chan = spec.channel or "(configured)"
    code = _errno(exc)
    names = _class_names(exc)
    options = [f"{k}={v}" for k, v in (("bitrate", spec.bitrate), ("data_bitrate", spec.data_bitrate)) if v is not None]
    options += [f"{k}={v}" for k, v in sorted(spec.options.items())]
    text = str(exc).lower()
    driver_missing = bool(names & {"ImportError", "NameError"}) or (
        "library" in text and ("not found" in text or "load" in text) and code is None)
    if not spec.interface and ("CanInterfaceNotImplementedError" in names or "unknown interface" in text):
        problem = "no interface given and none configured for python-can"
        todo = "name one (can:socketcan:vcan0, can:slcan:/dev/ttyACM0) or set CAN_INTERFACE / ~/.canrc"
    elif "CanInterfaceNotImplementedError" in names or driver_missing:
        if "unknown interface" in text:
            known = f" (python-can knows: {', '.join(sorted(interfaces))})" if interfaces else ""
            problem, todo = f"python-can has no interface {iface!r}{known}", "write can:INTERFACE:CHANNEL with one of them"
        else:
            problem = f"python-can's {iface!r} interface cannot be used on this machine ({_first_line(exc)})"
            todo = (f"install the driver/library the {iface!r} interface needs, or use another interface "
                    "(can:socketcan:CHANNEL, can:slcan:DEVICE, or can:slcan:pty for the emulated board)")
    elif code == errno.EAFNOSUPPORT:
        problem = "this kernel has no SocketCAN (CAN address family not supported)"
        todo = ("use can:slcan:pty, or run the command on a kernel with vcan: `ghostshell vcan -- COMMAND` "
                "(this machine's kernel, or User-Mode Linux)")
    elif code == errno.ENODEV:
        problem = f"there is no CAN network interface {chan!r}"
        todo = (f"create it (sudo ip link add dev {chan} type vcan && sudo ip link set up {chan}) "
                "or name an existing one (ip -brief link)")
    elif code in (errno.ENOENT, errno.ENXIO):
        problem = f"there is no device {chan!r}"
        todo = "check the adapter's path (ls /dev/ttyACM* /dev/ttyUSB*), or use can:slcan:pty for the emulated board"
    elif code in (errno.EACCES, errno.EPERM):
        problem = f"permission denied on {chan!r}"
        todo = "add your user to the group that owns the device (often dialout), or bring the interface up as root"
    elif code in (errno.EISDIR, errno.ENOTTY):
        problem = f"{chan!r} is not a serial device"
        todo = "give the adapter's tty, e.g. can:slcan:/dev/ttyACM0"
    elif code == errno.EBUSY:
        problem = f"{chan!r} is busy"
        todo = "close the other program using it"
    elif names & {"ValueError", "TypeError", "OverflowError", "error", "CanInitializationError"} and options:
        problem = f"python-can's {iface!r} interface refused {'&'.join(options)} ({_first_line(exc)})"
        todo = f"fix those option values (python-can's documentation of the {iface!r} interface lists them)"
    elif "TypeError" in names and not (spec.interface and spec.channel):
        missing = "channel" if spec.interface else "interface or channel"
        problem = f"no {missing} given or configured"
        todo = f"name the {missing}, e.g. can:slcan:/dev/ttyACM0, or set CAN_INTERFACE / CAN_CHANNEL or ~/.canrc"
    elif "CanError" in names:
        problem = f"python-can's {iface!r} interface could not start the bus ({_first_line(exc)})"
        todo = "check that the adapter is connected and the channel and options are right"
    elif "TypeError" in names:
        problem = f"python-can's {iface!r} interface needs settings a link spec does not carry ({_first_line(exc)})"
        todo = "give them in python-can's configuration (~/.canrc, can.ini), or use can:socketcan or can:slcan"
    else:
        problem = f"{type(exc).__name__}: {_first_line(exc)}"
        todo = "check the interface, channel and options of the link spec"
    return f"cannot open CAN bus {spec}: {problem}; {todo}"
