"""PID 1 inside a throwaway User-Mode Linux guest: set up SocketCAN, run one job, power off.

Started by :func:`host.tools.vcan.uml.run_in_uml` through a generated ``init`` script as
``python uml_init.py RUN_DIR/job.json``. The guest's root is the host's root through hostfs,
so every path means the same inside and out. Steps:

1. mount proc, sysfs, devtmpfs (or a tmpfs with the basic nodes), a private devpts instance
   (``newinstance``) with ``/dev/ptmx``, tmpfs on ``/run``, ``/dev/shm`` and ``/tmp`` (the host
   folders the job must reach — the run dir and ``keep`` paths — are bind-mounted back into the
   fresh ``/tmp``, so the guest never shares the host's ``/tmp`` otherwise);
2. load the CAN modules by path with the ``finit_module`` syscall (no kmod needed; the Debian
   package ships them under ``/usr/lib/uml/modules/<version>/``);
3. create the vcan interfaces with ``ip link`` (MTU 72 = CAN FD capable, optional txqueuelen);
4. run the job with the exact environment given, stdout/stderr into files in the run dir,
   killing it after its timeout (exit status 124, as coreutils ``timeout``); a command that is
   not found or not executable gets one line on its stderr and 127 / 126, as a shell gives;
5. copy the job's ``copy_back`` paths (``/tmp/NAME`` the host did not have) out of the guest's
   ``/tmp`` into the host's, through the host ``/tmp`` bound at ``/run/host-tmp``;
6. write ``exit_status`` atomically, ``sync``, and power off with ``sysrq o``. PID 1 never
   exits (a dying init panics the kernel); any failure of steps 1-3 is written to
   ``init_error.txt`` with exit status 125.

Hand-written on purpose: it must run with nothing but the Python standard library as init.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import json
import os
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

_MS_BIND = 4096
_MS_REC = 16384
_SYS_FINIT_MODULE = {"x86_64": 313, "aarch64": 273, "i686": 350, "i386": 350}

_libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)


def _mount(source: str, target: str, fstype: str | None, flags: int = 0, data: str | None = None) -> None:
    Path(target).mkdir(parents=True, exist_ok=True)
    rc = _libc.mount(
        source.encode(),
        target.encode(),
        fstype.encode() if fstype else None,
        ctypes.c_ulong(flags),
        data.encode() if data else None,
    )
    if rc != 0:
        err = ctypes.get_errno()
        raise OSError(err, f"mount {fstype or 'bind'} {source} on {target}: {os.strerror(err)}")


def _mount_dev() -> None:
    try:
        _mount("devtmpfs", "/dev", "devtmpfs")
    except OSError:
        _mount("tmpfs", "/dev", "tmpfs", data="mode=0755")
        for name, major, minor in (("null", 1, 3), ("zero", 1, 5), ("full", 1, 7), ("random", 1, 8), ("urandom", 1, 9), ("tty", 5, 0)):
            os.mknod(f"/dev/{name}", 0o666 | 0o020000, os.makedev(major, minor))
    _mount("devpts", "/dev/pts", "devpts", data="newinstance,ptmxmode=0666,mode=0620")
    ptmx = Path("/dev/ptmx")
    if ptmx.exists() or ptmx.is_symlink():
        ptmx.unlink()
    ptmx.symlink_to("pts/ptmx")
    _mount("tmpfs", "/dev/shm", "tmpfs", data="mode=1777")
    for fd, name in ((0, "stdin"), (1, "stdout"), (2, "stderr")):
        link = Path(f"/dev/{name}")
        if not link.exists():
            link.symlink_to(f"/proc/self/fd/{fd}")


def _mount_private_tmp(keep: list[str]) -> None:
    """A fresh tmpfs ``/tmp`` with the host folders in ``keep`` bind-mounted back at their paths."""
    _mount("tmpfs", "/run", "tmpfs", data="mode=0755")
    _mount("/tmp", "/run/host-tmp", None, _MS_BIND | _MS_REC)
    _mount("tmpfs", "/tmp", "tmpfs", data="mode=1777")
    for path in keep:
        if not path.startswith("/tmp/"):
            continue
        rel = path[len("/tmp/"):]
        _mount(f"/run/host-tmp/{rel}", path, None, _MS_BIND | _MS_REC)


def _load_modules(paths: list[str]) -> None:
    nr = _SYS_FINIT_MODULE.get(os.uname().machine)
    if nr is None:
        raise RuntimeError(f"finit_module syscall number unknown for {os.uname().machine}")
    for path in paths:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC)
        try:
            rc = _libc.syscall(nr, fd, b"", 0)
        finally:
            os.close(fd)
        err = ctypes.get_errno()
        if rc != 0 and err != 17:  # EEXIST: built in or loaded already
            raise OSError(err, f"finit_module {path}: {os.strerror(err)}")


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True, text=True, env={"PATH": "/usr/sbin:/usr/bin:/sbin:/bin"})


def _setup_vcans(vcans: list[str], mtu: int, txqueuelen: int | None) -> None:
    _ip("link", "set", "lo", "up")
    for name in vcans:
        _ip("link", "add", "dev", name, "type", "vcan")
        _ip("link", "set", name, "mtu", str(mtu))
        if txqueuelen is not None:
            _ip("link", "set", name, "txqueuelen", str(txqueuelen))
        _ip("link", "set", name, "up")


def _write_status(run_dir: Path, status: int) -> None:
    tmp = run_dir / "exit_status.tmp"
    with open(tmp, "w") as f:
        f.write(f"{status}\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, run_dir / "exit_status")


def _run_job(job: dict, run_dir: Path) -> int:
    with open(run_dir / "stdout.txt", "wb") as out, open(run_dir / "stderr.txt", "wb") as err:
        try:
            proc = subprocess.Popen(
                job["argv"],
                cwd=job["cwd"],
                env=job["env"],
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=err,
                start_new_session=True,
            )
        except (FileNotFoundError, PermissionError, NotADirectoryError) as e:
            missing = isinstance(e, FileNotFoundError) and not Path(job["cwd"]).is_dir()
            what = (f"working folder {job['cwd']} does not exist in the guest" if missing else
                    f"{job['argv'][0]}: {'command not found' if isinstance(e, FileNotFoundError) else e.strerror}")
            err.write(f"[uml] {what}\n".encode())
            return 127 if isinstance(e, FileNotFoundError) else 126
        try:
            status = proc.wait(timeout=job["timeout"])
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            err.write(f"\n[uml] job killed after its {job['timeout']} s timeout\n".encode())
            status = 124
        out.flush()
        err.flush()
        os.fsync(out.fileno())
        os.fsync(err.fileno())
    return status if status >= 0 else 128 - status


def _copy_back(paths: list[str], run_dir: Path) -> None:
    """Copy each guest ``/tmp/NAME`` the job left to the host's ``/tmp`` (bound at ``/run/host-tmp``),
    unless the host has one by now (a line on the job's stderr says so)."""
    import shutil

    for path in paths:
        src = Path(path)
        if not path.startswith("/tmp/") or not (src.exists() or src.is_symlink()):
            continue
        dst = Path("/run/host-tmp") / path[len("/tmp/"):]
        if dst.exists() or dst.is_symlink():
            with open(run_dir / "stderr.txt", "ab") as err:
                err.write(f"[uml] {path} exists outside the guest by now: the guest's was not copied out\n".encode())
            continue
        if src.is_dir() and not src.is_symlink():
            shutil.copytree(src, dst, symlinks=True)
        else:
            shutil.copy2(src, dst, follow_symlinks=False)
    os.sync()


def _power_off() -> None:
    os.sync()
    try:
        with open("/proc/sysrq-trigger", "w") as f:
            f.write("o")
    except OSError:
        pass
    while True:  # init must never exit
        time.sleep(3600)


def main(job_path: str) -> None:
    run_dir = Path(job_path).parent
    status = 125
    try:
        job = json.loads(Path(job_path).read_text())
        run_dir = Path(job["run_dir"])
        _mount("proc", "/proc", "proc")
        _mount("sysfs", "/sys", "sysfs")
        _mount_dev()
        _mount_private_tmp([str(run_dir), *job["keep"]])
        _load_modules(job["modules"])
        _setup_vcans(job["vcans"], job["mtu"], job["txqueuelen"])
    except BaseException:
        try:
            (run_dir / "init_error.txt").write_text(traceback.format_exc())
            _write_status(run_dir, 125)
        finally:
            _power_off()
    try:
        status = _run_job(job, run_dir)
    except BaseException:
        (run_dir / "init_error.txt").write_text(traceback.format_exc())
        status = 125
    try:
        _copy_back(job.get("copy_back", []), run_dir)
    except BaseException:
        with open(run_dir / "stderr.txt", "ab") as err:
            err.write(f"[uml] copying out of the guest's /tmp failed: {traceback.format_exc(limit=1)}".encode())
    try:
        _write_status(run_dir, status)
    finally:
        _power_off()


if __name__ == "__main__":
    main(sys.argv[1])
