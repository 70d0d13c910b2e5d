"""The ftcap MAVLink 2 dialect: ``ftcap.xml`` (includes common.xml) and its Python module.

Messages (ids 52800-52809 are reserved for this project; see ``ftcap.xml``):

* ``WRENCH_SETPOINT`` (52800): ground station -> allocator, body-frame wrench in N / N*m.
* ``FTCAP_STATUS`` (52801): allocator -> ground station, demanded and unallocated wrench plus
  the per-thruster fault estimate ``delta_hat`` / ``f_hat`` of one cycle, up to 16 thrusters.
  A typed message of our own rather than DEBUG_FLOAT_ARRAY / NAMED_VALUE_FLOAT: the two
  estimates of one cycle arrive together (atomically), with names and units, in one packet.

How the Python module is produced and shipped
---------------------------------------------
Only the XML is in the repository. :func:`load` runs pymavlink's own mavgen (Python 3,
MAVLink 2) on first use and caches the module under ``$FTCAP_MAVLINK_CACHE`` or
``$XDG_CACHE_HOME/ftcap-hil/mavlink`` (default ``~/.cache/ftcap-hil/mavlink``), in a file
named after a hash of the XML, the included XML and the pymavlink version, so an upgrade
regenerates it (why it is not committed: docs/decisions.md). Concurrent first starts (daemon,
vessel and ground station launched together) each write a private temporary file and
``os.replace`` it, so they never see a partial file.

pymavlink wheels do not ship ``message_definitions/``; they ship each bundled dialect's XML
next to its module in ``pymavlink/dialects/v20/`` (common.xml -> standard.xml ->
minimal.xml). mavgen resolves ``<include>`` relative to the including file, so the three are
copied next to our XML in a scratch directory.

To decode our messages in another tool (e.g. MAVProxy ``--dialect ftcap``), write the module
with ``python -m bridges.mavlink.dialect --out DIR`` and put it where that tool looks.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import importlib.util
import io
import os
import shutil
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType

__all__ = ["XML", "MESSAGE_IDS", "cache_dir", "load", "render"]

XML = Path(__file__).resolve().parent / "ftcap.xml"
MESSAGE_IDS = range(52800, 52810)
_INCLUDES = ("common.xml", "standard.xml", "minimal.xml")
_MODULE_NAME = "bridges.mavlink.dialect.ftcap"
_lock = threading.Lock()


def pymavlink_definitions_dir() -> Path:
    """Directory of the MAVLink 2 XML definitions bundled with the installed pymavlink."""
    spec = importlib.util.find_spec("pymavlink")
    if spec is None or spec.origin is None:
        raise RuntimeError("pymavlink is not installed")
    return Path(spec.origin).resolve().parent / "dialects" / "v20"


def _cache_key(xml: Path) -> str:
    digest = hashlib.sha256(importlib.metadata.version("pymavlink").encode())
    digest.update(xml.read_bytes())
    for name in _INCLUDES:
        digest.update((pymavlink_definitions_dir() / name).read_bytes())
    return digest.hexdigest()[:16]


def cache_dir() -> Path:
    """Where generated modules are cached (precedence: env override > XDG > home)."""
    if override := os.environ.get("FTCAP_MAVLINK_CACHE"):
        return Path(override)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ftcap-hil" / "mavlink"


def render(xml: Path = XML) -> str:
    """Run mavgen on ``xml`` (with the bundled common.xml) and return the module's source."""
    from pymavlink.generator import mavgen, mavparse

    with tempfile.TemporaryDirectory(prefix="ftcap-mavgen-") as tmp:
        work = Path(tmp)
        for name in _INCLUDES:
            shutil.copyfile(pymavlink_definitions_dir() / name, work / name)
        shutil.copyfile(xml, work / "ftcap.xml")
        out = work / "ftcap.py"
        opts = mavgen.Opts(
            str(out), wire_protocol=mavparse.PROTOCOL_2_0, language="Python3", validate=True
        )
        chatter = io.StringIO()  # mavgen reports progress on stdout
        with contextlib.redirect_stdout(chatter):
            try:
                ok = mavgen.mavgen(opts, [str(work / "ftcap.xml")])
            except SystemExit:  # mavgen exit()s on some validation errors
                ok = False
        if not ok or not out.exists():
            raise RuntimeError(f"mavgen failed for {xml}:\n{chatter.getvalue()}")
        return out.read_text(encoding="utf-8")


def _write_atomically(target: Path, source: str) -> None:
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=".ftcap-", suffix=".py.tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(source)
        os.chmod(tmp_name, 0o644)
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise


def _generated_path(xml: Path) -> Path:
    name = f"ftcap_{_cache_key(xml)}.py"
    # A read-only home (some containers) falls back to a per-user temporary directory.
    fallback = Path(tempfile.gettempdir()) / f"ftcap-hil-mavlink-{os.getuid()}"
    candidates = (cache_dir() / name, fallback / name)
    for target in candidates:
        if target.exists():
            return target
    source = render(xml)
    for target in candidates:
        try:
            _write_atomically(target, source)
        except OSError:
            continue
        return target
    raise OSError(f"cannot write the generated MAVLink dialect to any of {candidates}")


def load(xml: Path = XML) -> ModuleType:
    """The generated dialect module (MAVLink 2), generating it into the cache if missing.

    Idempotent and thread-safe; the module is registered as ``bridges.mavlink.dialect.ftcap``.
    """
    with _lock:
        cached = sys.modules.get(_MODULE_NAME)
        if cached is not None and xml == XML:
            return cached
        path = _generated_path(xml)
        name = _MODULE_NAME if xml == XML else f"{_MODULE_NAME}_{path.stem}"
        spec = importlib.util.spec_from_file_location(name, path)
        if spec is None or spec.loader is None:
            raise ImportError(f"cannot load generated MAVLink dialect {path}")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        sys.modules[name] = module
        return module
