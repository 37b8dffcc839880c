"""Safe publication of output files and folders: written under a unique temporary name beside the
target, published atomically when complete, removed on any failure.

- The temporary name is unique (``tempfile.mkstemp``: O_CREAT | O_EXCL), so two processes writing
  the same output never share a file. It is hidden (``.NAME.xxxx.partial.SUFFIX``) and lives in
  the target's folder, so publication is a rename within one file system.
- Publication without ``replace`` never replaces an existing file, even one another process
  created a moment ago: ``renameat2(RENAME_NOREPLACE)`` where the kernel and file system offer it,
  else a hard link (which fails if the target exists) followed by removing the temporary name,
  else (a file system without hard links) a check and a rename. With ``replace`` it is
  ``os.replace``. The data are flushed to the disk (``fsync``) before publication.
- The published file gets the permissions a plain ``open()`` would give (0666 less the umask),
  not mkstemp's private 0600.
- Any exception inside the ``with`` block removes the temporary file; an ``OSError`` (full disk,
  permission, read-only file system, a directory in the way, ...) becomes an ``OutputError`` whose
  one-line message names the file and the cause.
- Targets that are not plain files are refused: an existing folder, FIFO, device or socket, and
  anything inside the kernel's /proc, /sys or /dev (except /dev/shm).

Imports no physics engine.
"""

from __future__ import annotations

import contextlib
import contextvars
import ctypes
import errno
import os
import shutil
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from ..errors import OutputError

_REPLACE_HINT: contextvars.ContextVar[str] = contextvars.ContextVar("replace_hint", default="replace=True")


def replace_hint() -> str:
    """How the caller replaces an existing output: ``replace=True`` for a script, ``--force`` on
    the command line (``replace_hint_as``), named in the message of an output that exists."""
    return _REPLACE_HINT.get()


@contextlib.contextmanager
def replace_hint_as(text: str) -> Iterator[None]:
    """Within the block, messages about existing outputs name ``text`` (the CLI: "--force")."""
    token = _REPLACE_HINT.set(text)
    try:
        yield
    finally:
        _REPLACE_HINT.reset(token)


_CAUSES = {
    errno.ENOSPC: "no space left on the device",
    errno.EDQUOT: "disk quota exceeded",
    errno.EFBIG: "file too large (the file size limit of this process or file system)",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EROFS: "read-only file system",
    errno.EISDIR: "is a directory",
    errno.ENOTDIR: "a part of the path is not a directory",
    errno.ENOENT: "the folder does not exist",
    errno.ENOTEMPTY: "a folder of that name exists and is not empty",
    errno.ENAMETOOLONG: "the name is too long",
    errno.ELOOP: "too many symbolic links in the path",
    errno.EIO: "input/output error (the device failed)",
    errno.EMFILE: "too many open files",
    errno.EXDEV: "the temporary file and the target are on different file systems",
}

KERNEL_FOLDERS = ("/proc", "/sys", "/dev")
"""Folders of kernel objects, not files: no output goes there (``/dev/shm`` excepted)."""

_AT_FDCWD = -100
_RENAME_NOREPLACE = 1


def describe_os_error(exc: OSError) -> str:
    """A short cause for an OSError, without the path (callers name the path)."""
    if exc.errno == errno.EEXIST:
        return f"it exists (pass {replace_hint()} to replace it)"
    return _CAUSES.get(exc.errno or 0, exc.strerror or type(exc).__name__)


def output_error(path: str | os.PathLike[str], exc: OSError, *, action: str = "cannot write") -> OutputError:
    """The one-line error for an OSError while writing ``path``."""
    return OutputError(f"{action} {os.fspath(path)!r}: {describe_os_error(exc)}")


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def in_kernel_folder(path: str | os.PathLike[str]) -> str | None:
    """The kernel folder (/proc, /sys, /dev) that ``path`` resolves into, or None."""
    try:
        real = os.path.realpath(os.fspath(path))
    except (OSError, ValueError):
        return None
    if real == "/dev/shm" or real.startswith("/dev/shm/"):
        return None
    return next((k for k in KERNEL_FOLDERS if real == k or real.startswith(k + "/")), None)


def check_file_target(path: str | os.PathLike[str], *, replace: bool = False) -> Path:
    """Check that ``path`` can become an output file: not in /proc, /sys or /dev, not an existing
    folder, FIFO, device or socket, and (without ``replace``) not an existing file.

    Raises:
      OutputError: naming the path and the reason.
    """
    target = Path(path)
    kernel = in_kernel_folder(target)
    if kernel is not None:
        raise OutputError(f"output {str(target)!r} is inside {kernel}, which holds kernel objects, not files")
    try:
        mode = target.lstat().st_mode
    except FileNotFoundError:
        return target
    except OSError as exc:
        raise output_error(target, exc) from None
    if stat.S_ISLNK(mode):
        with contextlib.suppress(OSError):
            mode = target.stat().st_mode  # what the link points to, if anything
    if not (stat.S_ISREG(mode) or stat.S_ISLNK(mode)):
        raise OutputError(f"output {str(target)!r} is {_kind(mode)}; give a file name")
    if not replace:
        raise OutputError(f"output {str(target)!r} exists; choose another name or pass {replace_hint()} to replace it")
    return target


def check_folder_target(path: str | os.PathLike[str]) -> Path:
    """Check that ``path`` can become (or already is) an output folder.

    Raises:
      OutputError: it is inside /proc, /sys or /dev, or exists and is not a folder.
    """
    target = Path(path)
    kernel = in_kernel_folder(target)
    if kernel is not None:
        raise OutputError(f"output {str(target)!r} is inside {kernel}, which holds kernel objects, not files")
    try:
        mode = target.stat().st_mode
    except FileNotFoundError:
        return target
    except OSError as exc:
        raise output_error(target, exc) from None
    if not stat.S_ISDIR(mode):
        what = "a file" if stat.S_ISREG(mode) else _kind(mode)
        raise OutputError(f"output {str(target)!r} is {what}; give a folder")
    return target


def _umask() -> int:
    """The process's umask, without changing it where /proc tells it."""
    with contextlib.suppress(OSError, ValueError, StopIteration):
        with open("/proc/self/status") as f:
            line = next(line for line in f if line.startswith("Umask:"))
        return int(line.split()[1], 8)
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def temporary_sibling(path: Path, *, directory: bool = False, folder: Path | None = None) -> Path:
    """Create and return a uniquely named empty file (or folder) in ``folder`` (default: beside
    ``path``), hidden, whose name ends like ``path`` (so tools that infer the format from the
    suffix still do). Its permissions are those a plain ``open`` or ``mkdir`` would give."""
    parent = folder if folder is not None else (path.parent if str(path.parent) else Path("."))
    prefix = f".{path.name}."
    if directory:
        made = Path(tempfile.mkdtemp(dir=parent, prefix=prefix, suffix=".partial"))
        os.chmod(made, 0o777 & ~_umask())
        return made
    fd, name = tempfile.mkstemp(dir=parent, prefix=prefix, suffix=f".partial{path.suffix}")
    try:
        os.fchmod(fd, 0o666 & ~_umask())
    finally:
        os.close(fd)
    return Path(name)


def _load_renameat2() -> Any:
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        function = libc.renameat2
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    function.restype = ctypes.c_int
    return function


_renameat2 = _load_renameat2()


def rename_no_replace(source: Path, target: Path) -> None:
    """Rename ``source`` to ``target`` atomically, failing with FileExistsError if ``target``
    exists (renameat2 with RENAME_NOREPLACE). Raises NotImplementedError where the kernel, the C
    library or the file system lacks it."""
    if _renameat2 is None:
        raise NotImplementedError("renameat2 is not available")
    result = _renameat2(_AT_FDCWD, os.fsencode(source), _AT_FDCWD, os.fsencode(target), _RENAME_NOREPLACE)
    if result == 0:
        return
    code = ctypes.get_errno()
    if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
        raise NotImplementedError(os.strerror(code))
    raise OSError(code, os.strerror(code), str(target))


def publish(temporary: Path, path: Path, *, replace: bool) -> None:
    """Move a finished temporary file (or folder) to ``path``: atomically, and never over an
    existing one unless ``replace``."""
    if replace:
        os.replace(temporary, path)
        return
    with contextlib.suppress(NotImplementedError):
        rename_no_replace(temporary, path)
        return
    if temporary.is_dir():
        os.mkdir(path)  # fails if it exists; then the (empty) folder is replaced by the full one
        os.replace(temporary, path)
        return
    try:
        os.link(temporary, path)  # fails with EEXIST if path exists: no race with other writers
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EXDEV, errno.EMLINK):
            raise
        if path.exists() or path.is_symlink():  # a file system without hard links: check, then rename
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(path)) from None
        os.rename(temporary, path)
        return
    temporary.unlink()


def _sync(path: Path) -> None:
    """Flush a written file's data to the disk (a full disk may only say so here)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike[str], *, replace: bool = False) -> Iterator[Path]:
    """Write a file safely: ``with atomic_output("run.mcap") as tmp: write(tmp)``.

    Args:
      path: the file to publish.
      replace: replace an existing file (``--force``); otherwise an existing file is an error and
        stays untouched.

    Yields:
      The temporary path to write (it exists, empty).

    Raises:
      OutputError: the target exists (without ``replace``) or is not a plain file name (a folder,
        FIFO, device, /proc ...), or writing or publishing failed (full disk, permissions, ...).
        Nothing is left behind.
    """
    target = check_file_target(path, replace=replace)
    try:
        tmp = temporary_sibling(target)
    except OSError as exc:
        raise output_error(target, exc) from None
    try:
        try:
            yield tmp
        except OutputError as exc:  # from a writer inside: name the file the user gave
            raise OutputError(str(exc).replace(str(tmp), str(target))) from None
        _sync(tmp)
        publish(tmp, target, replace=replace)
    except FileExistsError:
        raise OutputError(
            f"output {str(target)!r} appeared while it was being written (another process?); it was left untouched"
        ) from None
    except OSError as exc:
        raise output_error(target, exc) from None
    finally:
        tmp.unlink(missing_ok=True)


def _nearest_existing_folder(path: Path) -> Path:
    folder = path.parent if str(path.parent) else Path(".")
    while not folder.is_dir() and folder != folder.parent:
        folder = folder.parent
    return folder


@contextlib.contextmanager
def atomic_directory(path: str | os.PathLike[str], *, replace: bool = False) -> Iterator[Path]:
    """Write a folder of outputs safely: the files go to a unique temporary folder; when the block
    completes they are published into ``path``: the whole folder at once if ``path`` does not
    exist (missing parent folders are created then), else file by file. Files of other names in
    ``path`` are left alone. On failure nothing is published and the temporary folder is removed.

    Args:
      path: the output folder.
      replace: replace files of the same names in an existing ``path`` (``--force``); otherwise
        any such file is an error before anything is moved.

    Raises:
      OutputError: ``path`` is a file or in /proc ..., a file of the same name exists (without
        ``replace``), or writing or moving failed. Nothing is left behind.
    """
    target = check_folder_target(path)
    base = _nearest_existing_folder(target)
    try:
        tmp = temporary_sibling(target, directory=True, folder=base)
    except OSError as exc:
        raise output_error(target, exc) from None
    moved: list[Path] = []
    try:
        try:
            yield tmp
        except OutputError as exc:  # from a writer inside: name the folder the user gave
            raise OutputError(str(exc).replace(str(tmp), str(target))) from None
        for item in tmp.iterdir():
            if item.is_file():
                _sync(item)
        if not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            with contextlib.suppress(FileExistsError):
                publish(tmp, target, replace=False)  # the whole folder at once
        if tmp.exists():
            items = sorted(tmp.iterdir())
            taken = [target / i.name for i in items if (target / i.name).exists() or (target / i.name).is_symlink()]
            if taken and not replace:
                more = f" (and {len(taken) - 1} more)" if len(taken) > 1 else ""
                raise OutputError(
                    f"output {str(taken[0])!r}{more} exists; choose another folder or pass {replace_hint()} to replace"
                )
            for item in items:
                publish(item, target / item.name, replace=replace)
                moved.append(target / item.name)
    except FileExistsError as exc:
        _withdraw(moved, replace=replace)
        raise OutputError(
            f"output {exc.filename!r} appeared while the folder was being written (another process?); "
            "nothing was published"
        ) from None
    except OSError as exc:
        _withdraw(moved, replace=replace)
        raise output_error(target, exc) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _withdraw(moved: list[Path], *, replace: bool) -> None:
    """After a failure while publishing a folder file by file: remove the files published so far
    (ours, a moment old). With ``replace`` they took the place of older files, which are gone
    either way, so the new ones stay."""
    if not replace:
        for done in moved:
            done.unlink(missing_ok=True)
