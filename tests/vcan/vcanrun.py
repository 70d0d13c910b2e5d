"""Run a command where a SocketCAN ``vcan0`` interface is up.

If this host can use ``vcan0`` (AF_CAN sockets work and ``vcan0`` exists or can be created),
the command runs here. Otherwise it runs in a throw-away qemu VM (TCG, one vCPU) that boots a
cached Debian kernel and initramfs built by ``tests/vcan/setup.sh``, mounts this host's root
read-only over virtio-9p, mounts ``cwd`` and the ``writable`` folders read-write at the same
paths, creates ``vcan0`` and runs the command chrooted into the host root, so the host's own
Python and virtual environment run unchanged inside the guest.

Library use::

    result = run_with_vcan([sys.executable, "-m", "pytest", "tests/vcan/inner_e2e.py"],
                           cwd=repo, timeout_s=600, writable=[out_dir])
    assert result.returncode == 0, result.output

Command line::

    python tests/vcan/vcanrun.py [--timeout S] [--writable DIR]... [--mode vm] -- CMD ARGS...

Environment: FTCAP_VCAN_MODE (auto|host|vm), FTCAP_VCAN_CACHE (the setup cache folder),
FTCAP_VCAN_MEM_MB (guest memory, default 1024), FTCAP_VCAN_ACCEL (qemu accelerator, default
tcg,thread=multi; kvm where it works), FTCAP_VCAN_SMP (vCPUs, default 2),
FTCAP_VCAN_KEEP=1 (keep the job folder).
"""

from __future__ import annotations

import argparse
import enum
import logging
import os
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

HERE = Path(__file__).resolve().parent
STAGE2 = HERE / "guest-stage2.sh"
SETUP_HINT = f"run: sudo bash {HERE / 'setup.sh'}"
POLL_S = 0.2
GUEST_HOME = "/tmp/vcanrun-home"
BOOT_MARK = "vcan-vm: stage 1"  # printed by the initramfs' init (guest-stage1.sh)
BOOT_TIMEOUT_S = 60.0  # it normally appears after ~2 s
BOOT_ATTEMPTS = 2

log = logging.getLogger(__name__)


class VcanMode(enum.Enum):
    AUTO = "auto"  # host if it can use vcan0, else vm
    HOST = "host"
    VM = "vm"


@dataclass(frozen=True)
class VcanResult:
    returncode: int
    output: str  # the command's stdout and stderr, interleaved
    mode: VcanMode  # HOST or VM: where it actually ran
    elapsed_s: float  # wall time, including the VM's boot and power-off
    console: str = ""  # the VM's serial console (kernel and guest set-up messages)


class VcanError(RuntimeError):
    """The command could not be run with vcan0 (not: the command failed)."""


class VcanUnavailable(VcanError):
    """Neither the host nor a VM can provide vcan0 (qemu or the setup cache is missing)."""


class VcanTimeout(VcanError):
    def __init__(self, message: str, output: str, console: str = "") -> None:
        super().__init__(message)
        self.output = output
        self.console = console


class VcanVmError(VcanError):
    def __init__(self, message: str, console: str) -> None:
        super().__init__(message)
        self.console = console


@dataclass(frozen=True)
class VmImage:
    kernel: Path
    initrd: Path


def host_has_vcan(iface: str = "vcan0", create: bool = True) -> bool:
    """True if AF_CAN works here and ``iface`` is up (created and raised if allowed)."""
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except (OSError, AttributeError):
        return False
    ip = shutil.which("ip") or "/sbin/ip"
    steps = [[ip, "link", "set", "dev", iface, "up"]]
    if not Path("/sys/class/net", iface).exists():
        if not create:
            return False
        steps.insert(0, [ip, "link", "add", "dev", iface, "type", "vcan"])
    for step in steps:
        try:
            done = subprocess.run(step, capture_output=True, timeout=10, check=False)
        except (OSError, subprocess.TimeoutExpired):
            return False
        if done.returncode != 0:
            return False
    return True


def cache_dir() -> Path:
    if "FTCAP_VCAN_CACHE" in os.environ:
        return Path(os.environ["FTCAP_VCAN_CACHE"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ftcap-hil" / "vcan-vm"


def find_vm_image() -> VmImage:
    """The kernel and initramfs built by setup.sh; VcanUnavailable if they are missing."""
    if shutil.which("qemu-system-x86_64") is None:
        raise VcanUnavailable(f"qemu-system-x86_64 not found; {SETUP_HINT}")
    current = cache_dir() / "current"
    if not current.is_file():
        raise VcanUnavailable(f"no VM image in {cache_dir()}; {SETUP_HINT}")
    folder = cache_dir() / current.read_text().strip()
    initrd = folder / "initrd.img"
    kernel = next((k for k in (folder / "vmlinux", folder / "vmlinuz") if k.is_file()), None)
    if kernel is None or not initrd.is_file():
        raise VcanUnavailable(f"incomplete VM image in {folder}; {SETUP_HINT}")
    return VmImage(kernel=kernel, initrd=initrd)


def unavailable_reason() -> str | None:
    """None if run_with_vcan can work here (on the host or in a VM), else why not."""
    if _resolve_mode(None) is VcanMode.HOST:
        return None
    try:
        find_vm_image()
    except VcanUnavailable as e:
        return str(e)
    return None


def run_with_vcan(
    argv: Sequence[str],
    *,
    cwd: str | os.PathLike[str],
    env: Mapping[str, str] | None = None,
    timeout_s: float,
    writable: Sequence[str | os.PathLike[str]] = (),
    mode: VcanMode | None = None,
    stream: BinaryIO | None = None,
) -> VcanResult:
    """Run ``argv`` in ``cwd`` where vcan0 is up; return its exit status and output.

    ``env`` replaces the environment (None: this process's). ``cwd`` and the ``writable``
    folders are writable in the VM and their contents come back to the host; everything else
    of the host root is read-only there, and /tmp is a fresh tmpfs. In the VM, HOME and TMPDIR
    point into /tmp unless they lie in a writable folder, and PYTHONDONTWRITEBYTECODE=1.
    ``stream``, if given, receives the output as it comes. The command's failure is data
    (``returncode``); VcanTimeout after ``timeout_s`` (the VM or the process group is killed),
    VcanUnavailable or VcanVmError when vcan0 could not be provided.
    """
    if not argv:
        raise ValueError("argv is empty")
    cwd = os.path.abspath(cwd)
    if not os.path.isdir(cwd):
        raise ValueError(f"cwd {cwd!r} is not a folder")
    env = dict(os.environ if env is None else env)
    keep = os.environ.get("FTCAP_VCAN_KEEP") == "1"
    job = Path(tempfile.mkdtemp(prefix="vcanrun-"))
    try:
        if _resolve_mode(mode) is VcanMode.HOST:
            return _run_host(list(argv), cwd, env, timeout_s, job, stream)
        shares = _writable_shares([cwd, *(os.fspath(w) for w in writable), str(job)])
        return _run_vm(list(argv), cwd, _guest_env(env, shares), timeout_s, job, shares, stream)
    finally:
        if keep:
            log.warning("vcanrun: kept job folder %s", job)
        else:
            shutil.rmtree(job, ignore_errors=True)


def _resolve_mode(mode: VcanMode | None) -> VcanMode:
    if mode is None:
        name = os.environ.get("FTCAP_VCAN_MODE", "auto")
        try:
            mode = VcanMode(name)
        except ValueError:
            raise ValueError(f"FTCAP_VCAN_MODE={name!r}: expected auto, host or vm") from None
    if mode is VcanMode.AUTO:
        return VcanMode.HOST if host_has_vcan() else VcanMode.VM
    return mode


def _run_host(
    argv: list[str],
    cwd: str,
    env: dict[str, str],
    timeout_s: float,
    job: Path,
    stream: BinaryIO | None,
) -> VcanResult:
    out_path = job / "output"
    start = time.monotonic()
    with open(out_path, "wb") as out:
        proc = subprocess.Popen(
            argv,
            cwd=cwd,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        outcome = _wait(proc, start + timeout_s, out_path, stream)
    finally:
        if proc.poll() is None:  # timeout or interrupt: the whole group we started goes
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    output = _read_text(out_path)
    if outcome is _Wait.TIMED_OUT:
        raise VcanTimeout(f"{shlex.join(argv)} still running after {timeout_s:g} s; killed", output)
    return VcanResult(proc.returncode, output, VcanMode.HOST, time.monotonic() - start)


def _writable_shares(paths: Sequence[str]) -> list[str]:
    """Real paths, parents first, without those already inside another share."""
    real = sorted({os.path.realpath(p) for p in paths}, key=lambda p: (p.count("/"), p))
    shares: list[str] = []
    for path in real:
        if path == "/" or "\n" in path or not os.path.isdir(path):
            raise ValueError(f"writable folder {path!r} must be an existing folder other than /")
        if not any(_inside(path, s) for s in shares):
            shares.append(path)
    return shares


def _inside(path: str, folder: str) -> bool:
    return path == folder or path.startswith(folder.rstrip("/") + "/")


def _guest_env(env: dict[str, str], shares: Sequence[str]) -> dict[str, str]:
    env = dict(env)
    for key, fallback in (("HOME", GUEST_HOME), ("TMPDIR", "/tmp")):
        value = os.path.realpath(env.get(key, fallback))
        if value != fallback and not any(_inside(value, s) for s in shares):
            env[key] = fallback  # the host's value is read-only or hidden by /tmp's tmpfs
    env.setdefault("PYTHONDONTWRITEBYTECODE", "1")
    return env


def _write_job(
    job: Path, argv: list[str], cwd: str, env: dict[str, str], shares: Sequence[str]
) -> None:
    shutil.copy(STAGE2, job / "guest-stage2.sh")
    (job / "jobdir").write_text(f"{job.resolve()}\n")
    (job / "mounts").write_text("".join(f"rw{i} {p}\n" for i, p in enumerate(shares)))
    exports = " ".join(shlex.quote(f"{k}={v}") for k, v in sorted(env.items()))
    (job / "run.sh").write_text(
        f"mkdir -p {GUEST_HOME}\n"
        f"cd {shlex.quote(cwd)} || exit 126\n"
        f"exec /usr/bin/env -i {exports} {shlex.join(argv)}\n"
    )


def _qemu_argv(image: VmImage, job: Path, shares: Sequence[str]) -> list[str]:
    # TCG by default: a host's KVM may be unusable (nested or paravirtual). Two vCPUs on
    # multi-threaded TCG: the HIL run's vessel overran 12 of 515 steps instead of 239 of 303
    # on one vCPU (tests/vcan/README.md). -no-reboot with panic=-1 turns a guest kernel panic
    # into a qemu exit.
    fixed = "-M pc -cpu max -nodefaults -no-user-config -display none -nic none -no-reboot"
    argv = ["qemu-system-x86_64", *fixed.split()]
    argv += ["-smp", os.environ.get("FTCAP_VCAN_SMP", "2")]
    argv += ["-accel", os.environ.get("FTCAP_VCAN_ACCEL", "tcg,thread=multi")]
    argv += ["-m", os.environ.get("FTCAP_VCAN_MEM_MB", "1024")]
    argv += ["-serial", f"file:{_qemu_path(job / 'console.log')}"]
    argv += ["-kernel", str(image.kernel), "-initrd", str(image.initrd)]
    argv += ["-append", "console=ttyS0 panic=-1 quiet"]
    exports = [("hostroot", "/", True), ("job", str(job), False)]
    exports += [(f"rw{i}", path, False) for i, path in enumerate(shares)]
    for i, (tag, path, readonly) in enumerate(exports):
        fsdev = f"local,id=fs{i},path={_qemu_path(path)},security_model=none,multidevs=remap"
        argv += [
            "-fsdev",
            fsdev + (",readonly=on" if readonly else ""),
            "-device",
            f"virtio-9p-pci,fsdev=fs{i},mount_tag={tag}",
        ]
    return argv


def _qemu_path(path: str | Path) -> str:
    return str(path).replace(",", ",,")  # qemu option lists escape a comma by doubling it


def _run_vm(
    argv: list[str],
    cwd: str,
    env: dict[str, str],
    timeout_s: float,
    job: Path,
    shares: Sequence[str],
    stream: BinaryIO | None,
) -> VcanResult:
    image = find_vm_image()
    _write_job(job, argv, cwd, env, shares)
    start = time.monotonic()
    for attempt in range(1, BOOT_ATTEMPTS + 1):
        outcome, qemu_rc = _boot_once(image, job, shares, start + timeout_s, stream)
        if outcome is not _Wait.NO_BOOT:
            break
        log.warning(
            "vcanrun: the VM did not reach its init within %g s (attempt %d of %d)",
            BOOT_TIMEOUT_S,
            attempt,
            BOOT_ATTEMPTS,
        )
    console = "".join(_read_text(job / name) for name in ("console.log", "setup.log", "qemu.log"))
    output = _read_text(job / "output")
    if outcome is _Wait.TIMED_OUT:
        raise VcanTimeout(
            f"{shlex.join(argv)} still running in the VM after {timeout_s:g} s;"
            f" qemu killed. Console tail:\n{_tail(console)}",
            output,
            console,
        )
    rc_text = _read_text(job / "rc").strip()
    if outcome is _Wait.NO_BOOT or (job / "setup-error").exists() or not rc_text.isdigit():
        raise VcanVmError(
            f"the VM stopped ({outcome.value}, qemu exit {qemu_rc}) without"
            f" running the command. Console tail:\n{_tail(console)}",
            console,
        )
    return VcanResult(int(rc_text), output, VcanMode.VM, time.monotonic() - start, console)


def _boot_once(
    image: VmImage, job: Path, shares: Sequence[str], deadline: float, stream: BinaryIO | None
) -> tuple[_Wait, int | None]:
    for name in ("console.log", "qemu.log", "output", "rc", "setup.log", "setup-error"):
        (job / name).unlink(missing_ok=True)
    with open(job / "qemu.log", "wb") as qemu_log:
        qemu = subprocess.Popen(
            _qemu_argv(image, job, shares),
            stdin=subprocess.DEVNULL,
            stdout=qemu_log,
            stderr=subprocess.STDOUT,
        )
    try:
        outcome = _wait(qemu, deadline, job / "output", stream, job / "console.log")
    finally:
        if qemu.poll() is None:
            qemu.kill()  # by its PID: only the qemu we started
            qemu.wait()
    return outcome, qemu.returncode


class _Wait(enum.Enum):
    EXITED = "exited"
    TIMED_OUT = "timed out"
    NO_BOOT = "no boot"


def _wait(
    proc: subprocess.Popen[bytes],
    deadline: float,
    out_path: Path,
    stream: BinaryIO | None,
    console: Path | None = None,
) -> _Wait:
    """Wait for ``proc``, copying new output to ``stream``.

    With ``console``, NO_BOOT if the guest's init has not said BOOT_MARK within BOOT_TIMEOUT_S:
    a kernel that hangs in early boot is retried rather than waited out.
    """
    boot_deadline = time.monotonic() + BOOT_TIMEOUT_S if console is not None else None
    sent = 0
    while True:
        try:
            proc.wait(timeout=POLL_S)
            exited = True
        except subprocess.TimeoutExpired:
            exited = False
        if stream is not None:
            sent = _copy_new(out_path, sent, stream)
        if exited:
            return _Wait.EXITED
        now = time.monotonic()
        if now >= deadline:
            return _Wait.TIMED_OUT
        if console is not None and boot_deadline is not None and now >= boot_deadline:
            if BOOT_MARK not in _read_text(console):
                return _Wait.NO_BOOT
            boot_deadline = None


def _copy_new(path: Path, offset: int, stream: BinaryIO) -> int:
    try:
        with open(path, "rb") as f:
            f.seek(offset)
            data = f.read()
    except FileNotFoundError:
        return offset
    if data:
        stream.write(data)
        stream.flush()
    return offset + len(data)


def _read_text(path: Path) -> str:
    try:
        return path.read_bytes().decode(errors="replace")
    except FileNotFoundError:
        return ""


def _tail(text: str, lines: int = 30) -> str:
    return "\n".join(text.splitlines()[-lines:])


def main(args: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds (default 600)")
    parser.add_argument("--cwd", default=os.getcwd(), help="working folder (default: here)")
    parser.add_argument(
        "--writable",
        action="append",
        default=[],
        metavar="DIR",
        help="another folder the command may write to (repeatable)",
    )
    parser.add_argument(
        "--mode",
        choices=[m.value for m in VcanMode],
        default=None,
        help="auto (default, or FTCAP_VCAN_MODE), host or vm",
    )
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- CMD ARGS...")
    opts = parser.parse_args(args)
    command = opts.command[1:] if opts.command[:1] == ["--"] else opts.command
    if not command:
        parser.error("no command given (python vcanrun.py -- CMD ARGS...)")
    try:
        result = run_with_vcan(
            command,
            cwd=opts.cwd,
            timeout_s=opts.timeout,
            writable=opts.writable,
            stream=sys.stdout.buffer,
            mode=VcanMode(opts.mode) if opts.mode else None,
        )
    except VcanError as e:
        print(f"vcanrun: {e}", file=sys.stderr)
        return 124 if isinstance(e, VcanTimeout) else 125
    print(
        f"vcanrun: exit {result.returncode} in {result.elapsed_s:.1f} s ({result.mode.value})",
        file=sys.stderr,
    )
    return result.returncode


if __name__ == "__main__":
    sys.exit(main())
