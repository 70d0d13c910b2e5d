"""The ftcap MAVLink 2 dialect: ``ftcap.xml`` (includes common.xml) and its Python module.

Messages (ids 52800-52809 are reserved for this project; see ``ftcap.xml``):

* ``WRENCH_SETPOINT`` (52800): ground station -> allocator, body-frame wrench in N / N*m.
* ``FTCAP_STATUS`` (52801): allocator -> ground station, demanded and unallocated wrench plus
  the per-thruster fault estimate ``delta_hat`` (with its standard deviation) / ``f_hat`` of
  one cycle, up to 16 thrusters. A typed message of our own rather than DEBUG_FLOAT_ARRAY /
  NAMED_VALUE_FLOAT: the estimates of one cycle arrive together (atomically), with names and
  units, in one packet.
* ``FTCAP_ESC_STATUS`` (52802): the ESC telemetry as the allocator sees it.
* ``FTCAP_THRUST`` (52803): the commanded thruster forces in N.

How the Python module is produced and where it is imported from
----------------------------------------------------------------
Only the XML is in the repository. :func:`load` runs pymavlink's own mavgen (Python 3,
MAVLink 2) on first use and caches the module in :func:`cache_dir`
(``$FTCAP_MAVLINK_CACHE``, else ``$XDG_CACHE_HOME/ftcap-hil/mavlink``, else
``~/.cache/ftcap-hil/mavlink``), in a file named after a hash of the XML, the included XML
and the pymavlink version, so an upgrade regenerates it. The cache is code that gets
imported, so it must be private: a directory this process creates is made with mode 0700; an
existing directory (and the module file in it) is used only if it is a real directory (not a
symlink) owned by this user or by root and not writable by group or others (root-owned and
read-only: an image built at install time). Otherwise, or when the cache cannot be written
(a read-only home), the module is generated into a fresh ``tempfile.mkdtemp`` directory
(random name, mode 0700) for this process only: never a predictable shared path.
Concurrent first starts write a private temporary file each and ``os.replace`` it.

pymavlink wheels do not ship ``message_definitions/``; they ship each bundled dialect's XML
next to its module in ``pymavlink/dialects/v20/`` (common.xml -> standard.xml ->
minimal.xml). mavgen resolves ``<include>`` relative to the including file, so the three are
copied next to our XML in a scratch directory.

For pymavlink's tools, ``python -m bridges.mavlink.dialect --install`` writes the module as
``pymavlink/dialects/v20/ftcap.py`` of the installed pymavlink, where ``mavutil.set_dialect``
(MAVProxy ``--dialect=ftcap``, ``mavlogdump.py --dialect ftcap``, ``MAVLINK_DIALECT=ftcap``)
imports it from (:mod:`bridges.mavlink.dialect.__main__`).
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import importlib.util
import io
import logging
import os
import re
import shutil
import stat
import sys
import tempfile
import threading
from pathlib import Path
from types import ModuleType

__all__ = ["XML", "MESSAGE_IDS", "cache_dir", "load", "render", "install", "is_private", "share"]

XML = Path(__file__).resolve().parent / "ftcap.xml"
MESSAGE_IDS = range(52800, 52810)
STANDARD_IDS = {290: "ESC_INFO", 291: "ESC_STATUS"}  # common.xml's, missing from pymavlink's
_INCLUDES = ("common.xml", "standard.xml", "minimal.xml")
_MODULE_NAME = "bridges.mavlink.dialect.ftcap"
_lock = threading.Lock()
_scratch: list[Path] = []  # per-process fallback directories (mkdtemp), reused by this process
logger = logging.getLogger(__name__)


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


def is_private(path: Path, *, directory: bool) -> bool:
    """``path`` is safe to import code from: not a symlink, the expected kind, owned by this
    user or root, and not writable by group or others."""
    try:
        st = path.lstat()
    except OSError:
        return False
    kind_ok = stat.S_ISDIR(st.st_mode) if directory else stat.S_ISREG(st.st_mode)
    owner_ok = st.st_uid in (os.getuid(), 0)
    return kind_ok and owner_ok and not st.st_mode & (stat.S_IWGRP | stat.S_IWOTH)


def _private_dir(path: Path) -> Path | None:
    """``path`` as a private directory, created with mode 0700 if missing; None if it exists
    but is not private, or cannot be created."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.mkdir(mode=0o700)
    except FileExistsError:
        pass
    except OSError:
        return None
    if is_private(path, directory=True):
        return path
    logger.warning("MAVLink dialect cache %s is not private (owner or mode): not used", path)
    return None


def _without_bundled(text: str) -> str:
    """Our XML less the standard messages the bundled common.xml already defines."""
    common = (pymavlink_definitions_dir() / "common.xml").read_text(encoding="utf-8")
    for msg_id, name in STANDARD_IDS.items():
        if f'name="{name}"' in common:
            block = re.compile(rf'\s*<message id="{msg_id}" name="{name}">.*?</message>', re.S)
            text = block.sub("", text)
    return text


def render(xml: Path = XML) -> str:
    """Run mavgen on ``xml`` (with the bundled common.xml) and return the module's source."""
    from pymavlink.generator import mavgen, mavparse

    with tempfile.TemporaryDirectory(prefix="ftcap-mavgen-") as tmp:
        work = Path(tmp)
        for name in _INCLUDES:
            shutil.copyfile(pymavlink_definitions_dir() / name, work / name)
        text = _without_bundled(xml.read_text(encoding="utf-8"))
        (work / "ftcap.xml").write_text(text, encoding="utf-8")
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


def write_atomically(target: Path, source: str, mode: int = 0o600) -> None:
    """Write ``source`` to ``target`` through a private temporary file and ``os.replace``."""
    fd, tmp_name = tempfile.mkstemp(dir=target.parent, prefix=".ftcap-", suffix=".py.tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(source)
        os.chmod(tmp_name, mode)
        os.replace(tmp_name, target)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp_name)
        raise


def _scratch_dir() -> Path:
    if not _scratch:
        _scratch.append(Path(tempfile.mkdtemp(prefix="ftcap-mavlink-")))  # mode 0700
    return _scratch[0]


def _generated_path(xml: Path) -> Path:
    name = f"ftcap_{_cache_key(xml)}.py"
    cache = _private_dir(cache_dir())
    if cache is not None:
        target = cache / name
        if is_private(target, directory=False):
            return target
        if not target.exists():
            source = render(xml)
            with contextlib.suppress(OSError):
                write_atomically(target, source)
                return target
    # Read-only home, or a cache that is not ours: this process's own random directory.
    target = _scratch_dir() / name
    if not target.exists():
        write_atomically(target, render(xml))
    return target


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


def share(module: Path) -> None:
    """Make a cached module and its directory readable (not writable) by every user: an
    image generates the cache as root at build time and runs as another user."""
    module.chmod(0o644)
    module.parent.chmod(0o755)


V10_ALIAS = '''"""The ftcap dialect for a mavutil program started without MAVLINK20 (written by
``python -m bridges.mavlink.dialect --install``): the project's messages exist in MAVLink 2
only (ids above 255), so this is the MAVLink 2 module. Its codec reads MAVLink 1 frames too,
and mavutil switches to MAVLink 2 at the first MAVLink 2 frame."""

import sys

from pymavlink.dialects.v20 import ftcap as _v20

sys.modules[__name__] = _v20
'''


def install(directory: Path | None = None) -> list[Path]:
    """Write ``ftcap.py`` and ``ftcap.xml`` into ``directory`` (default: the installed
    pymavlink's ``dialects/v20``), where ``mavutil.set_dialect("ftcap")`` imports them from,
    and the alias module ``V10_ALIAS`` as ``ftcap.py`` in the sibling ``v10`` directory, where
    ``MAVLINK_DIALECT=ftcap`` without ``MAVLINK20`` looks first (mavutil's import would
    otherwise raise). Returns the paths written; OSError if a directory is not writable."""
    target_dir = directory or pymavlink_definitions_dir()
    target_dir.mkdir(parents=True, exist_ok=True)
    module = target_dir / "ftcap.py"
    write_atomically(module, render(), mode=0o644)
    xml = target_dir / "ftcap.xml"
    shutil.copyfile(XML, xml)
    alias_dir = target_dir.parent / "v10"
    alias_dir.mkdir(exist_ok=True)
    alias = alias_dir / "ftcap.py"
    write_atomically(alias, V10_ALIAS, mode=0o644)
    return [module, xml, alias]
