"""Where pendsim's numba kernels are cached, and one line when numba compiles them (a cold cache:
the first run after installing, a new numba, or a new ``NUMBA_CACHE_DIR``), so that a first
command that is silent for seconds says why. pendsim_mj prints nothing itself: the command line
sets the notice (``set_notice``), a script may too. Loaded cache entries say nothing.

Each module that defines kernels calls ``watch()`` right after importing numba and before its
first ``@numba.njit``; it does two things, once per process:

- **The cache folder.** Where numba keeps what it compiled is chosen when a function is
  decorated. Unless numba already has a folder (``NUMBA_CACHE_DIR``, or ``cache_dir`` in a
  ``.numba_config.yaml``), pendsim sets ``NUMBA_CACHE_DIR`` to ``cache_folder()``: the user's
  cache folder for pendsim, one subfolder per numba version and version of the kernels that
  inline each other across files (``~/.cache/pendsim/numba-0.68.1-1a2b3c4d`` on Linux,
  ``$XDG_CACHE_HOME`` if set; numba adds one subfolder per source folder). Without
  it numba writes beside the source (``__pycache__``), falls back to ``~/.cache/numba`` when the
  source is read-only, and refuses to import a kernel module at all ("cannot cache function")
  when neither is writable; and environments with different numba versions that share a
  source tree (editable installs) overwrite each other's entries. Where the user's cache
  folder is not writable either, the kernels are kept in a temporary folder for this process
  only (compiled again on every run; the line says so). The variable is set in ``os.environ``,
  so that child processes (workers, subprocesses) use the same folder.
- **The notice.** One listener for numba's "numba:compile" event, which numba triggers only
  when a function is compiled, never when it is loaded from its cache.
"""

from __future__ import annotations

import atexit
import hashlib
import os
import shutil
import tempfile
from collections.abc import Callable
from typing import Any

COLD_COMPILE_S = "about 5-60 s of CPU, a sweep's the most; longer on a busy machine"
"""What a cold compile costs a command (2 cores, 2026-11-26: allan 2-3 s, validate and identify
13-19 s, a sweep's parallel kernel 11-15 s more; 2026-11-27 on a slower machine: validate 18 s,
a 6-case frequency sweep 62 s of CPU, measured by a fresh user's trial)."""

_notice: Callable[[str], None] | None = None
_said = False
_watching = False
_kept = True  # False: the kernels live in a temporary folder for this process only


INLINING_PACKAGES = ("engines/fast_planar",)
"""pendsim_mj's packages whose kernels inline helpers defined in another of their files."""


def sources_digest(folders: tuple[str, ...] = INLINING_PACKAGES) -> str:
    """8 hex digits of a SHA-256 over the Python sources of ``folders`` (relative to pendsim_mj):
    what the cache folder's name carries, because numba's ``cache=True`` notices an edit only in
    the file a cached function is defined in, and a kernel that inlines another file's helper
    would otherwise load its old compiled code after that helper changed."""
    root = os.path.dirname(os.path.abspath(__file__))
    digest = hashlib.sha256()
    for folder in folders:
        path = os.path.join(root, folder)
        for name in sorted(os.listdir(path)):
            if name.endswith(".py"):
                digest.update(name.encode())
                with open(os.path.join(path, name), "rb") as source:
                    digest.update(source.read())
    return digest.hexdigest()[:8]


def cache_folder() -> str:
    """pendsim's default numba cache folder: the user's cache folder for pendsim (numba's own
    rule: ``$XDG_CACHE_HOME`` or ``~/.cache`` on Linux, ``~/Library/Caches`` on macOS,
    ``%LOCALAPPDATA%`` on Windows), one subfolder per numba version and version of the kernels'
    shared sources (``sources_digest``): ``numba-0.68.1-1a2b3c4d``. numba must be importable."""
    import numba
    from numba.misc.appdirs import AppDirs  # numba's copy of appdirs: the rule numba's own cache uses

    name = f"numba-{numba.__version__}-{sources_digest()}"
    return os.path.join(AppDirs(appname="pendsim", appauthor=False).user_cache_dir, name)


def _writable(folder: str) -> bool:
    try:
        os.makedirs(folder, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()  # as numba checks a cache folder
    except OSError:
        return False
    return True


def _use_cache_folder() -> None:
    """Set ``NUMBA_CACHE_DIR`` to ``cache_folder()`` unless numba has a cache folder already
    (the module docstring); a temporary one where that is not writable."""
    global _kept
    from numba.core import config

    # the user's folder (NUMBA_CACHE_DIR or numba's config file) is respected
    if config.CACHE_DIR:  # type: ignore[attr-defined]
        return
    folder = cache_folder()
    if not _writable(folder):
        folder = tempfile.mkdtemp(prefix="pendsim-numba-")
        atexit.register(shutil.rmtree, folder, ignore_errors=True)
        _kept = False
    os.environ["NUMBA_CACHE_DIR"] = folder
    config.reload_config()  # numba reads its environment again: CACHE_DIR for the decorators that follow


def set_notice(notice: Callable[[str], None] | None) -> None:
    """Call ``notice`` with one line, once per process, when numba first compiles a kernel."""
    global _notice
    _notice = notice


def _cache_folder(dispatcher: Any) -> str:
    """Where numba keeps the compiled kernels: the cache folder (NUMBA_CACHE_DIR, which numba fills
    with one subfolder per source folder), else where it keeps this function (beside the source)."""
    folder = os.environ.get("NUMBA_CACHE_DIR")
    if folder:
        return folder
    cache = getattr(dispatcher, "_cache", None)
    path = getattr(cache, "_cache_path", None)
    return str(path) if path else "numba's cache folder"


def message(dispatcher: Any) -> str:
    """The line said on a cold compile, naming where the result is kept."""
    if not _kept:
        return (
            f"compiling the numba kernels this command needs ({COLD_COMPILE_S}; not kept: no writable cache folder, "
            "set NUMBA_CACHE_DIR to one)"
        )
    folder = _cache_folder(dispatcher)
    return f"compiling the numba kernels this command needs, once ({COLD_COMPILE_S}; cached in {folder})"


def watch() -> None:
    """Choose the cache folder and listen for numba compiling (once per process; numba must be
    importable; call it before the module's first ``@numba.njit``)."""
    global _watching
    if _watching:
        return
    _use_cache_folder()
    from numba.core import event  # start-up: called by modules that have just imported numba

    class _Listener(event.Listener):
        def on_start(self, ev: Any) -> None:
            global _said
            if _said or _notice is None:
                return
            _said = True
            _notice(message(ev.data.get("dispatcher") if isinstance(ev.data, dict) else None))

        def on_end(self, ev: Any) -> None:
            pass

    event.register("numba:compile", _Listener())
    _watching = True
