"""``ghostshell eval --ray ADDRESS`` refuses an address with no Ray cluster behind it at once, in one line,
exit 2 (``ray.init`` alone retried for minutes and ended in a traceback, exit 1). No cluster is started."""

from __future__ import annotations

import socket
from pathlib import Path

import pytest

from host.cli import main as cli
from host.tools.eval.ray_backend import RayUnreachable, host_port, probe


def _closed_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("address, want", [
    ("auto", None), ("local", None), ("10.0.0.5:6379", ("10.0.0.5", 6379)),
    ("ray://head.lan:10001", ("head.lan", 10001)), ("[::1]:6379", ("::1", 6379)), ("head.lan", None),
])
def test_host_port(address: str, want: tuple[str, int] | None) -> None:
    assert host_port(address) == want


def test_a_bad_port_is_refused() -> None:
    with pytest.raises(RayUnreachable, match="the port is not a number 1-65535"):
        host_port("head:99999")


def test_probe_passes_a_listening_port_and_refuses_a_closed_one() -> None:
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        probe(f"127.0.0.1:{server.getsockname()[1]}")
    port = _closed_port()
    with pytest.raises(RayUnreachable, match=rf"--ray 127.0.0.1:{port}: cannot reach a Ray cluster there \(Connection refused\)"):
        probe(f"127.0.0.1:{port}")


def test_cli_unreachable_address_is_one_line_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'ghostshell[ray]'); the --ray backend is optional")
    out = tmp_path / "ev"
    address = f"127.0.0.1:{_closed_port()}"
    assert cli(["eval", "--llm", "ground-truth", "--tasks", "1", "--trials", "1", "--quiet", "--ray", address,
                "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"ghostshell eval: --ray {address}: cannot reach a Ray cluster"), err
    assert not out.exists()  # refused before anything was written
