"""A board the host started that died before its link came up is a lost link (exit 1), not a usage error (2):
:func:`host.link.board_process.dead_board_error`, which ``ghostshell run`` and ``ghostshell tour`` use."""

from __future__ import annotations

from pathlib import Path

from host.commands.linkarg import link_exit_status
from host.link.board_process import dead_board_error, start_board
from host.link.errors import LinkConfigError, LinkDown, LinkTimeout


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
        assert str(dead).startswith(f"before the link came up, the emulated board exited (status {status})")
        assert str(dead).endswith(f"; see {tmp_path / 'board.stderr'}")
        assert link_exit_status(dead) == 1
    finally:
        board.stop()


def test_a_client_never_reconnects_to_the_pty_of_a_board_that_died(tmp_path: Path) -> None:
    """``BoardProcess.link_target()``, what ``ghostshell run`` connects to: the pty of a board that died
    goes back to the kernel, which hands the same name to the next pty opened (seen in CI: another
    test's board); a host reconnecting by path took that board over. Now every reconnect fails with the
    dead board's exit status and last words, and the client stays down."""
    import anyio
    import pytest

    from host.link import BoardClient

    board = start_board(["--lockstep"], tmp_path / "board.stderr", link="pty")
    target = board.link_target()
    assert target() == board.spec  # while it runs: its link
    others = []

    async def main() -> None:
        c = await BoardClient.connect(target, reconnect_max_s=0.05)
        try:
            assert c.connected  # handshake done
            board.proc.kill()
            status = board.proc.wait()
            assert await c.wait_disconnected(5)
            # the next pty opened (often under the dead board's name): a live board the client must not take
            others.append(start_board(["--lockstep"], tmp_path / "other.stderr", link="pty"))
            with pytest.raises(LinkTimeout):
                await c.wait_connected(1.0)
            assert not c.connected and c.stats.reconnects == 0
            assert c.last_reconnect_error.startswith(f"the emulated board exited (status {status})"), c.last_reconnect_error
        finally:
            await c.close()

    try:
        anyio.run(main, backend="asyncio")
        with pytest.raises(LinkDown, match=r"the emulated board exited \(status -9\).*see .*board.stderr"):
            target()
    finally:
        board.stop()
        for other in others:
            other.stop()


def test_a_board_dead_before_the_first_connect_is_a_lost_link_naming_its_exit(tmp_path: Path) -> None:
    import anyio
    import pytest

    from host.link import BoardClient

    board = start_board(["--lockstep"], tmp_path / "board.stderr", link="pty")
    try:
        board.proc.kill()
        status = board.proc.wait()

        async def main() -> None:
            await BoardClient.connect(board.link_target())

        with pytest.raises(LinkDown) as e:
            anyio.run(main, backend="asyncio")
        assert not isinstance(e.value, LinkConfigError) and link_exit_status(e.value) == 1
        assert str(e.value).startswith(f"the emulated board exited (status {status})"), e.value
    finally:
        board.stop()
