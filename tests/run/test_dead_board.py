"""A board the host started that died before its link came up is a lost link (exit 1), not a usage error (2):
:func:`host.link.board_process.dead_board_error`, which ``ghostshell run`` and ``ghostshell tour`` use."""

from __future__ import annotations

from pathlib import Path

from host.commands.linkarg import link_exit_status
from host.link.board_process import dead_board_error, start_board
from host.link.errors import LinkConfigError, LinkDown


def test_a_dead_board_turns_a_link_config_error_into_a_lost_link(tmp_path: Path) -> None:
    refused = LinkConfigError("cannot open /dev/pts/99")
    assert link_exit_status(refused) == 2
    assert dead_board_error(None, refused) is None  # no board of ours: the spec is to blame
    board = start_board(["--lockstep"], tmp_path / "board.stderr", link="pty")
    try:
        assert dead_board_error(board, refused) is None  # it still runs: the error stands
        board.proc.kill()
        status = board.proc.wait()
        dead = dead_board_error(board, refused)
        assert isinstance(dead, LinkDown) and not isinstance(dead, LinkConfigError)
        assert str(dead) == (f"the emulated board exited (status {status}) before the link came up; "
                             f"see {tmp_path / 'board.stderr'}")
        assert link_exit_status(dead) == 1
    finally:
        board.stop()
