"""Outputs are published atomically under unique temporary names, never over an existing file
unless asked, and nothing is left behind by a failure (pendsim_bridge.io.outputs)."""

import contextlib
import errno
import os
import shutil
import stat
import subprocess
import sys
import tempfile
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

from pendsim_bridge.errors import OutputError
from pendsim_bridge.io.outputs import atomic_directory, atomic_output, rename_no_replace, replace_hint_as


def test_the_file_appears_only_when_complete(tmp_path):
    target = tmp_path / "out.txt"
    with atomic_output(target) as tmp:
        tmp.write_text("data")
        assert not target.exists()
        assert tmp.parent == tmp_path and tmp.name.startswith(".out.txt.") and tmp.suffix == ".txt"
    assert target.read_text() == "data"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_a_failure_leaves_nothing_behind(tmp_path):
    with pytest.raises(RuntimeError), atomic_output(tmp_path / "out.txt") as tmp:
        tmp.write_text("half")
        raise RuntimeError("writer failed")
    assert list(tmp_path.iterdir()) == []


def test_an_existing_file_is_refused_and_untouched_unless_replace(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    # a script is told its own way to replace (replace=True), the command line --force
    with pytest.raises(OutputError, match=r"exists; choose another name or pass replace=True"), atomic_output(target):
        pass
    with pytest.raises(OutputError, match="or pass --force"), replace_hint_as("--force"), atomic_output(target):
        pass
    with pytest.raises(OutputError, match=r"folder or pass replace=True"), atomic_directory(tmp_path) as folder:
        (folder / "out.txt").write_text("x")
    assert target.read_text() == "old"
    with atomic_output(target, replace=True) as tmp:
        tmp.write_text("new")
    assert target.read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_two_processes_writing_one_output_never_share_a_file_and_one_wins(tmp_path):
    script = textwrap.dedent(
        """
        import sys, time
        from pathlib import Path
        from pendsim_bridge.errors import OutputError
        from pendsim_bridge.io.outputs import atomic_output
        target, tag, barrier = Path(sys.argv[1]), sys.argv[2], Path(sys.argv[3])
        try:
            with atomic_output(target) as tmp:
                tmp.write_text(tag * 100000)
                (barrier / tag).touch()
                while len(list(barrier.iterdir())) < 2:  # both are writing now
                    time.sleep(0.01)
        except OutputError as exc:
            print("refused:", exc)
            sys.exit(3)
        """
    )
    barrier = tmp_path / "barrier"
    barrier.mkdir()
    target = tmp_path / "out.txt"
    procs = [
        subprocess.Popen([sys.executable, "-c", script, str(target), tag, str(barrier)], stdout=subprocess.PIPE)
        for tag in "ab"
    ]
    codes = sorted(p.wait(timeout=60) for p in procs)
    assert codes == [0, 3]
    content = target.read_text()
    assert content in ("a" * 100000, "b" * 100000)  # one writer's whole file, never a mix
    assert sorted(p.name for p in tmp_path.iterdir()) == ["barrier", "out.txt"]


def test_a_folder_of_outputs_is_published_together_or_not_at_all(tmp_path):
    out = tmp_path / "report"
    with pytest.raises(RuntimeError), atomic_directory(out) as tmp:
        (tmp / "a.json").write_text("{}")
        raise RuntimeError("figure failed")
    assert list(tmp_path.iterdir()) == []
    with atomic_directory(out) as tmp:
        (tmp / "a.json").write_text("{}")
        (tmp / "b.png").write_bytes(b"png")
    assert sorted(p.name for p in out.iterdir()) == ["a.json", "b.png"]
    (out / "keep.txt").write_text("mine")
    with pytest.raises(OutputError, match=r"a\.json' exists; choose another folder"), atomic_directory(out) as tmp:
        (tmp / "a.json").write_text('{"new": 1}')
        (tmp / "c.png").write_bytes(b"png")
    assert (out / "a.json").read_text() == "{}" and not (out / "c.png").exists()  # nothing published
    with atomic_directory(out, replace=True) as tmp:
        (tmp / "a.json").write_text('{"new": 1}')
    assert (out / "a.json").read_text() == '{"new": 1}' and (out / "keep.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report"]


def test_a_file_in_the_way_of_an_output_folder_is_an_error(tmp_path):
    (tmp_path / "report").write_text("x")
    with pytest.raises(OutputError, match="is a file; give a folder"), atomic_directory(tmp_path / "report"):
        pass


# -- real failures: full, read-only and forbidden file systems ---------------------------------
# A small tmpfs is a real full disk (ENOSPC) and, mounted read-only, a real EROFS. Mounting needs
# root (CAP_SYS_ADMIN); elsewhere these tests skip and test_full_disk.py falls back to a file size
# limit (RLIMIT_FSIZE, EFBIG). Permissions do not stop root: EACCES runs as user "nobody" there.


@contextlib.contextmanager
def tmpfs(path: Path, *, size: str = "256k", read_only: bool = False) -> Iterator[Path]:
    """Mount a tmpfs at ``path`` for the block (skip the test where mounting is impossible)."""
    path.mkdir()
    options = f"size={size},mode=0777" + (",ro" if read_only else "")
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root and mount(8)")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "pendsim-test", str(path)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def fill(folder: Path) -> None:
    """Write a filler file until the file system is full."""
    with open(folder / "filler", "wb", buffering=0) as f:
        block = b"\0" * 65536
        try:
            while True:
                f.write(block)
        except OSError as exc:
            assert exc.errno == errno.ENOSPC
        with contextlib.suppress(OSError):
            while True:
                f.write(b"\0" * 512)


def test_a_full_disk_is_one_error_naming_the_file_and_leaves_nothing(tmp_path):
    with tmpfs(tmp_path / "disk") as disk:
        fill(disk)
        full = r"cannot write '.*out\.bin': no space left on the device"
        with pytest.raises(OutputError, match=full), atomic_output(disk / "out.bin") as tmp:
            tmp.write_bytes(b"x" * 100000)
        with pytest.raises(OutputError, match="no space left on the device"), atomic_directory(disk / "report") as tmp:
            (tmp / "a.json").write_bytes(b"x" * 100000)
        assert sorted(p.name for p in disk.iterdir()) == ["filler"]


def test_a_read_only_file_system_is_one_error_and_the_existing_file_stays(tmp_path):
    with tmpfs(tmp_path / "ro", read_only=True) as ro:
        with (
            pytest.raises(OutputError, match=r"cannot write '.*x\.bin': read-only file system"),
            atomic_output(ro / "x.bin"),
        ):
            pass
        with pytest.raises(OutputError, match="read-only file system"), atomic_directory(ro / "report"):
            pass
        assert list(ro.iterdir()) == []


def test_a_folder_in_the_way_when_publishing_is_one_error(tmp_path):
    target = tmp_path / "out.bin"
    with pytest.raises(OutputError, match="is a directory"), atomic_output(target, replace=True) as tmp:
        tmp.write_bytes(b"data")
        target.mkdir()  # appears while the data are written (EISDIR on rename)
    (target / "inside").write_text("kept")
    assert [p.name for p in tmp_path.iterdir()] == ["out.bin"] and (target / "inside").read_text() == "kept"


def test_a_file_as_a_folder_of_the_path_is_one_error(tmp_path):
    (tmp_path / "plain.txt").write_text("x")
    with (
        pytest.raises(OutputError, match="a part of the path is not a directory"),
        atomic_output(tmp_path / "plain.txt" / "x.bin"),
    ):
        pass
    assert (tmp_path / "plain.txt").read_text() == "x"


def test_a_target_that_appears_while_writing_is_never_replaced(tmp_path):
    target = tmp_path / "out.bin"
    with pytest.raises(OutputError, match="appeared while it was being written"), atomic_output(target) as tmp:
        tmp.write_bytes(b"mine")
        target.write_bytes(b"theirs")  # another process, a moment before publication
    assert target.read_bytes() == b"theirs" and [p.name for p in tmp_path.iterdir()] == ["out.bin"]


@pytest.mark.parametrize("kind", ["fifo", "device", "proc", "folder"])
def test_special_targets_are_refused_even_with_replace(tmp_path, kind):
    if kind == "fifo":
        target = tmp_path / "pipe.bin"
        os.mkfifo(target)
    elif kind == "device":
        target = Path("/dev/null")
    elif kind == "proc":
        target = Path("/proc/self/pendsim.bin")
    else:
        target = tmp_path / "folder.bin"
        target.mkdir()
    with (
        pytest.raises(OutputError, match=r"FIFO|inside /dev|inside /proc|a folder"),
        atomic_output(target, replace=True),
    ):
        pass
    assert target.exists() or kind == "proc"


def test_published_files_get_the_permissions_open_would_give(tmp_path):
    old = os.umask(0o027)
    try:
        with atomic_output(tmp_path / "f.bin") as tmp:
            tmp.write_bytes(b"x")
        with atomic_directory(tmp_path / "d") as tmp:
            (tmp / "a").write_bytes(b"x")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "f.bin").stat().st_mode) == 0o640  # 0666 & ~027, not mkstemp's 0600
    assert stat.S_IMODE((tmp_path / "d").stat().st_mode) == 0o750  # 0777 & ~027, not mkdtemp's 0700


def test_no_replace_publication_is_one_atomic_rename_where_the_kernel_offers_it(tmp_path):
    source, target = tmp_path / "a", tmp_path / "b"
    source.write_text("new")
    target.write_text("old")
    try:
        rename_no_replace(source, target)
    except NotImplementedError:
        pytest.skip("renameat2(RENAME_NOREPLACE) is not available here; publication uses link and unlink")
    except FileExistsError:
        pass
    assert target.read_text() == "old" and source.read_text() == "new"
    rename_no_replace(source, tmp_path / "c")
    assert (tmp_path / "c").read_text() == "new" and not source.exists()


def test_permission_denied_is_one_error_line_for_an_unprivileged_user(tmp_path):
    """EACCES: root ignores permissions, so as root the command runs without the capabilities that
    override them (setpriv drops CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH and CAP_FOWNER from the
    bounding set): still root, so it can read the checkout wherever it lies, but bound by the
    mode bits like any user."""
    base = Path(tempfile.mkdtemp(prefix="pendsim-eacces-"))  # tmp_path's parents are private to root
    try:
        base.chmod(0o755)
        locked = base / "locked"
        locked.mkdir(mode=0o555)
        locked.chmod(0o555)
        command = [
            sys.executable, "-c",
            "import sys; from pendsim_bridge.cli import main; sys.exit(main(sys.argv[1:]))",
            "simulate", "--duration-s", "1", "-o", str(locked / "x.npz"),
        ]  # fmt: skip
        if os.geteuid() == 0:
            drop = ["setpriv", "--bounding-set=-dac_override,-dac_read_search,-fowner", "--"]
            if shutil.which("setpriv") is None or subprocess.run([*drop, "true"], capture_output=True).returncode:
                pytest.skip("running as root and unable to drop CAP_DAC_OVERRIDE: permissions cannot be tested")
            command = [*drop, *command]
        env = {**os.environ, "MUJOCO_GL": "disable"}  # (no GLFW probe: it re-executes Python)
        out = subprocess.run(command, cwd=base, env=env, capture_output=True, text=True, timeout=120)
        lines = out.stderr.splitlines()
        assert out.returncode == 2 and len(lines) == 1, out.stderr
        assert lines[0] == f"pendsim: error: output directory '{locked}' is not writable (permission denied)"
        assert list(locked.iterdir()) == []
    finally:
        shutil.rmtree(base, ignore_errors=True)
