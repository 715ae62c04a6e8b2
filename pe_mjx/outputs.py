"""One way to write an output, and one way to read an input: every command goes through here.

Writing (`write_file`, `writing`, `writing_dir`):

* the target must be a regular file (or, for a directory output, a directory) or not exist: a
  device node (/dev/null), a FIFO or a socket is refused, whatever `--force` says, and so is a
  directory where a file is to be written;
* an existing target is refused unless `force` (the command's `--force`);
* the content goes to a temporary beside the target (same directory, so same file system),
  renamed over the target once complete: a Ctrl-C, a `kill -9` or a full disk leaves the old
  target as it was, never a half-written one. A directory output is built in a temporary
  directory beside it and moved into place by one rename (Linux: `renameat2(RENAME_EXCHANGE)`
  where the target exists), so it appears whole or not at all;
* temporaries are named `.<target name>.pe-mjx-tmp-<pid>-<random><suffix>`; those of a process
  that no longer runs (a killed run) are removed by the next write into that directory.

Reading (`read_bytes`, `read_text`): at most `cap` + 1 bytes are read, whatever the file is (a
regular file, /dev/zero, a pipe), so that a wrong path is one line, not a read that never ends.

Standard library only (the lowest layer, beside `interrupts`).
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import re
import secrets
import shutil
import stat
from collections.abc import Callable, Iterator
from pathlib import Path

from pe_mjx import interrupts

TEMP_MARK = ".pe-mjx-tmp-"
"""Marks a temporary of this module in its name (see `temp_path`)."""
_TEMP_RE = re.compile(r"^\..+" + re.escape(TEMP_MARK) + r"(?P<pid>\d+)-[0-9a-f]{8}(\.[^.]*)?$")


class OutputError(ValueError):
    """A target that cannot be written as asked: its message is the one line a user sees."""


def _label(path: Path, flag: str | None) -> str:
    return f"{flag}: {path}" if flag else str(path)


def _kind(mode: int) -> str:
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a regular file"


def check_target(
    path: str | Path, *, force: bool = False, flag: str | None = None, directory: bool = False
) -> Path:
    """`path` as a target that may be written (an `OutputError` naming `flag` and the path if
    not): it does not exist, or is a regular file (a directory, for `directory`) and `force`.
    Its parent directory must exist. Symbolic links are followed for the check; the link itself
    is what gets replaced. A link to nothing counts as an existing file (replaced only with
    `force`) and is never a directory output."""
    path = Path(path)
    label = _label(path, flag)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        mode = None
    except OSError as err:
        raise OutputError(f"{label}: cannot be written: {err.strerror or err}") from None
    # A link to nothing: an evaluation ran to its end, then could not rename its results over
    # it, and they were lost.
    if mode is None and os.path.islink(path) and (directory or not force):
        raise OutputError(
            f"{label} is a symbolic link to {os.readlink(path)}, which does not exist; "
            "remove the link or give another path"
        )
    if mode is not None:
        if directory and not stat.S_ISDIR(mode):
            what = "a file" if stat.S_ISREG(mode) else _kind(mode)
            raise OutputError(f"{label} is {what}, not a directory; give a directory to write")
        if not directory and stat.S_ISDIR(mode):
            raise OutputError(f"{label} is a directory; give the path of the file to write")
        if not directory and not stat.S_ISREG(mode):
            raise OutputError(f"{label} is {_kind(mode)}, not a regular file; refused")
        if not force:
            raise OutputError(f"{label} exists; pass --force to overwrite it")
    parent = path.parent
    if not parent.is_dir():
        raise OutputError(f"{label}: directory {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise OutputError(f"{label}: directory {parent} is not writable")
    return path


def temp_path(target: Path, *, keep_suffix: bool = True) -> Path:
    """A fresh name beside `target` for its temporary: `.<name>.pe-mjx-tmp-<pid>-<hex><suffix>`
    (the suffix kept, so that writers that go by it, matplotlib and imageio, write the format)."""
    suffix = target.suffix if keep_suffix and 1 < len(target.suffix) <= 8 else ""
    name = f".{target.name}{TEMP_MARK}{os.getpid()}-{secrets.token_hex(4)}{suffix}"
    return target.parent / name


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def clean_stale(directory: str | Path) -> list[Path]:
    """Removes the temporaries in `directory` left by processes that no longer run (a run
    killed midway); returns them. Another user's, and those of running processes, stay."""
    removed = []
    try:
        entries = list(os.scandir(directory))
    except OSError:
        return removed
    for entry in entries:
        found = _TEMP_RE.match(entry.name)
        if found is None or _alive(int(found.group("pid"))):
            continue
        try:
            if entry.stat(follow_symlinks=False).st_uid != os.getuid():
                continue
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
        except OSError:
            continue
        removed.append(Path(entry.path))
    return removed


def _remove(path: Path) -> None:
    with contextlib.suppress(OSError):
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink()


@contextlib.contextmanager
def writing(
    path: str | Path, *, force: bool = False, flag: str | None = None, mode: int = 0o644
) -> Iterator[Path]:
    """The path of a fresh temporary beside `path` for a writer that wants a path (matplotlib,
    numpy, imageio); renamed over `path` when the block ends without an error, removed if it
    raises. The target is checked before (`check_target`) and again just before the rename."""
    target = check_target(path, force=force, flag=flag)
    clean_stale(target.parent)
    tmp = temp_path(target)
    try:
        with interrupts.removed_on_exit(lambda: _remove(tmp)):
            yield tmp
        if not tmp.is_file():
            raise OutputError(f"{_label(target, flag)}: nothing was written")
        interrupts.check()  # a Ctrl-C during the write: the target stays as it was
        check_target(target, force=force, flag=flag)
        os.chmod(tmp, mode & ~_umask())
        os.replace(tmp, target)
    except BaseException:
        _remove(tmp)
        raise


def write_file(
    path: str | Path,
    data: bytes | str | Callable[[Path], None],
    *,
    force: bool = False,
    flag: str | None = None,
    mode: int = 0o644,
) -> Path:
    """Writes `data` (bytes, text, or a function that writes the file at the path it is given)
    to `path` through a temporary renamed into place (see `writing`); returns `path`."""
    with writing(path, force=force, flag=flag, mode=mode) as tmp:
        if callable(data):
            data(tmp)
        else:
            raw = data.encode() if isinstance(data, str) else data
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
            with os.fdopen(fd, "wb") as f:
                f.write(raw)
    return Path(path)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_RENAME_EXCHANGE = 2


def _exchange(a: Path, b: Path) -> bool:
    """Swaps two paths atomically (Linux `renameat2(RENAME_EXCHANGE)`); False if unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd = -100
    result = renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), _RENAME_EXCHANGE)
    if result == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), str(b))


def _link_tree(src: Path, dst: Path) -> None:
    """Every entry of `src` that `dst` lacks, hard-linked (copied where links fail) into `dst`."""
    for entry in os.scandir(src):
        target = dst / entry.name
        if entry.is_dir(follow_symlinks=False):
            if target.is_dir() and not target.is_symlink():
                _link_tree(Path(entry.path), target)
            elif not os.path.lexists(target):
                shutil.copytree(entry.path, target, symlinks=True, copy_function=_link_or_copy)
        elif not os.path.lexists(target):
            _link_or_copy(entry.path, target)


def _link_or_copy(src: str | Path, dst: str | Path) -> None:
    if os.path.islink(src):
        os.symlink(os.readlink(src), dst)
        return
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


@contextlib.contextmanager
def writing_dir(path: str | Path, *, flag: str | None = None) -> Iterator[Path]:
    """A fresh temporary directory beside `path` to build a directory output in; when the
    block ends without an error it becomes `path` by one rename, so `path` appears whole or not
    at all (a Ctrl-C or `kill -9` midway leaves the old `path` as it was, and a temporary that
    the next write there removes). An existing `path` keeps its entries that the new output
    lacks (hard links, not copies), then the two swap atomically (Linux; elsewhere `path` is
    missing between two renames). Removed if the block raises."""
    target = check_target(path, force=True, flag=flag, directory=True)
    clean_stale(target.parent)
    stage = temp_path(target, keep_suffix=False)
    stage.mkdir(mode=0o777)
    try:
        with interrupts.removed_on_exit(lambda: _remove(stage)):
            yield stage
        interrupts.check()
        _commit_dir(stage, target)
    except BaseException:
        _remove(stage)
        raise


def _commit_dir(stage: Path, target: Path) -> None:
    try:
        os.rename(stage, target)  # absent, or an empty directory: replaced at once
        return
    except OSError as err:
        if err.errno not in (errno.ENOTEMPTY, errno.EEXIST):
            raise
    _link_tree(target, stage)
    if _exchange(stage, target):
        _remove(stage)  # now the old directory
        return
    old = temp_path(target, keep_suffix=False)
    os.rename(target, old)
    os.rename(stage, target)
    _remove(old)


def read_bytes(path: str | Path, cap: int, *, flag: str | None = None) -> bytes:
    """The bytes of `path`, reading at most `cap` + 1 of them (an `OutputError`, a ValueError
    naming `flag` and the path, if it holds more, is a device or cannot be read): safe on
    /dev/zero, a FIFO with no writer (empty) or a pipe (read, up to `cap`)."""
    path = Path(path)
    label = _label(path, flag)
    too_large = f"{label}: larger than {cap:,} bytes; refused"
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a FIFO: no wait
    except OSError as err:
        raise OutputError(f"{label}: cannot read: {err.strerror or err}") from None
    try:
        info = os.fstat(fd)
        if stat.S_ISDIR(info.st_mode):
            raise OutputError(f"{label} is a directory; give a file")
        # A device holds no file to read (/dev/zero would fill `cap` bytes of memory, 512 MB for
        # a results.json, before the refusal); a regular file says its size before any read.
        if stat.S_ISCHR(info.st_mode) or stat.S_ISBLK(info.st_mode):
            raise OutputError(f"{label} is a device, not a file; refused")
        if stat.S_ISREG(info.st_mode) and info.st_size > cap:
            raise OutputError(too_large)
        with contextlib.suppress(OSError, AttributeError):
            os.set_blocking(fd, True)
        chunks, size = [], 0
        while size <= cap:
            try:
                chunk = os.read(fd, min(1 << 20, cap + 1 - size))
            except OSError as err:
                raise OutputError(f"{label}: cannot read: {err.strerror or err}") from None
            if not chunk:
                break
            chunks.append(chunk)
            size += len(chunk)
        if size > cap:
            raise OutputError(too_large)
        return b"".join(chunks)
    finally:
        os.close(fd)


def read_text(path: str | Path, cap: int, *, flag: str | None = None) -> str:
    """`read_bytes` decoded as UTF-8 (an `OutputError` if it is not)."""
    try:
        return read_bytes(path, cap, flag=flag).decode()
    except UnicodeDecodeError:
        raise OutputError(f"{_label(Path(path), flag)}: not UTF-8 text") from None


__all__ = [
    "TEMP_MARK",
    "OutputError",
    "check_target",
    "clean_stale",
    "read_bytes",
    "read_text",
    "temp_path",
    "write_file",
    "writing",
    "writing_dir",
]
