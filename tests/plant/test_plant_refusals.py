"""Plant options that name nothing there are refused before the pty opens: one line naming the option and
its valid range, exit status 2 (a fresh user's ``--baud 0``, ``--missing 99``, ``--scene nosuch`` served or
gave a traceback)."""

from __future__ import annotations

import pytest

from firmware_sim.plant import server


@pytest.mark.parametrize(("argv", "says"), [
    (["--baud", "0"], "--baud 0: the baud rate must be 1..12000000"),
    (["--baud", "-5"], "--baud -5: the baud rate must be 1..12000000"),
    (["--missing", "99"], "--missing 99: no such device on the bus; coco's servo ids are 1..12, the IMU 0xF0"),
    (["--robot", "arm", "--missing", "7"], "--missing 7: no such device on the bus; arm's servo ids are 1..6"),
    (["--dead-servo", "99@1"], "--dead-servo 99: no such device on the bus; coco's servo ids are 1..12"),
    (["--dead-servo", "1@-1"], "--dead-servo 1@-1: the time must be 0 or more"),
    (["--reverse", "0"], "--reverse 0: 0 is not a servo; coco's servo ids are 1..12"),
    (["--model", "3=-1"], "--model 3=-1: a model number must be 0..65535"),
    (["--model", "13=777"], "--model 13=777: 13 is not a servo; coco's servo ids are 1..12"),
    (["--error", "99=overload@1"], "--error 99=...: 99 is not a servo; coco's servo ids are 1..12"),
    (["--offset", "77=5"], "--offset 77=5: 77 is not a servo; coco's servo ids are 1..12"),
    (["--duplicate", "13"], "--duplicate 13: no such device on the bus"),
    (["--scene", "nosuch"], "--scene nosuch: coco has no such scene; scenes: empty, bottles"),
])
def test_options_that_name_nothing_there_are_refused_in_one_line(
        argv: list[str], says: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    def no_pty() -> None:
        raise AssertionError("the pty was opened: the option was accepted")

    monkeypatch.setattr(server, "PtyPort", no_pty)
    assert server.main(["--robot", "coco", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("plant: ") and says in err[0], err


def test_the_devices_besides_the_servos_are_accepted_by_the_device_options() -> None:
    args = server.parser().parse_args(["--missing", "0xF0", "--dead-servo", "0xF1@1", "--duplicate", "12"])
    assert server.refusal(args, "coco", list(range(1, 13))) is None
