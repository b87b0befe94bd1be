"""Locks on output and run folders, and the temporaries of dead processes.

A folder is written by one process at a time: :class:`FolderLock` holds an exclusive
``flock`` on ``.NAME.lock`` beside the folder, with the holder's PID in it. The kernel drops
the lock when its process dies (SIGKILL included), so a stale lock file is taken over by
the next process. Temporaries are named ``.NAME.tmp-PID`` / ``.NAME.old-PID``: one whose
process is gone is removed by the next writer (a live process's are its work in progress).
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import fcntl
import os
import shutil
from pathlib import Path
from typing import Any

from qsls.pipeline.core.errors import BusyError, UnwritableError

TMP_MARK = ".tmp-"
OLD_MARK = ".old-"
LOCK_SUFFIX = ".lock"


def pid_alive(pid: int) -> bool:
    """Whether process ``pid`` exists (on this machine)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def unwritable(target: Path, exc: OSError, what: str = "output") -> UnwritableError:
    """One line for an output location that cannot be written: which folder, and why."""
    where = Path(exc.filename).parent if exc.filename else Path(target).parent
    why = exc.strerror or type(exc).__name__
    return UnwritableError(
        f"cannot write the {what} {target}: folder {where} is not writable ({why}); "
        "choose another --out"
    )


def check_writable(target: Path, what: str = "output") -> None:
    """Refuse now (before a long computation) when ``target`` cannot be created: its
    nearest existing ancestor is not a writable folder (read-only mount, no permission, a
    file). Creates nothing; the writers still turn a later ``OSError`` into one line."""
    target = Path(target).absolute()
    parent = target.parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise unwritable(
            target, NotADirectoryError(errno.ENOTDIR, "not a folder", str(parent / "x")), what
        )
    if not os.access(parent, os.W_OK | os.X_OK):
        code = errno.EROFS if _read_only(parent) else errno.EACCES
        raise unwritable(target, OSError(code, os.strerror(code), str(parent / "x")), what)


def _read_only(folder: Path) -> bool:
    try:
        return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except OSError:
        return False


def make_parent(target: Path, what: str = "output") -> None:
    """Create ``target``'s parent folders; an unwritable location is one line."""
    try:
        Path(target).parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise unwritable(target, exc, what) from None


def lock_path(target: Path) -> Path:
    """The lock file of a folder: ``.NAME.lock`` beside it (outside, as the folder itself is
    replaced by a rename)."""
    target = Path(target)
    return target.with_name(f".{target.name}{LOCK_SUFFIX}")


class FolderLock:
    """An exclusive ``flock`` on ``.NAME.lock`` beside a folder, holding this process's PID.

    The kernel releases the lock when its process dies (also on SIGKILL), so a lock file
    left by a dead process is simply taken over. Refused with one line naming the holder
    when a live process holds it.
    """

    def __init__(self, target: Path, what: str = "output folder") -> None:
        self.target = Path(target)
        self.path = lock_path(self.target)
        self.what = what
        self._fd: int | None = None
        self._owner = 0

    def acquire(self) -> FolderLock:
        while True:
            try:
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
            except OSError as exc:
                raise unwritable(self.target, exc, self.what) from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                os.close(fd)
                if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    raise
                raise BusyError(self._busy_message()) from None
            try:  # the file may have been unlinked by its last holder meanwhile: retry
                same = os.fstat(fd).st_ino == os.stat(self.path).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd
        self._owner = os.getpid()
        return self

    def release(self) -> None:
        if self._fd is None:
            return
        if self._owner == os.getpid():  # never from a forked child: the parent holds it
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *exc: Any) -> None:
        self.release()

    def _busy_message(self) -> str:
        try:
            holder = self.path.read_text().strip()
        except OSError:
            holder = ""
        who = f"another qsls process (pid {holder})" if holder else "another qsls process"
        return (
            f"{self.target}: {who} is writing this {self.what} right now; wait for it to "
            "finish, or choose another folder"
        )


_HELD: dict[str, FolderLock] = {}


@atexit.register
def release_all() -> None:
    """Release every output lock this process holds (at exit, and when a command ends: a
    stage that failed before writing leaves no lock file behind)."""
    for key in list(_HELD):
        _HELD.pop(key).release()


def hold_output(out: Path) -> None:
    """Lock ``out`` for this process until :func:`release_output` (idempotent)."""
    key = os.path.realpath(out)
    if key not in _HELD:
        _HELD[key] = FolderLock(Path(out)).acquire()


def check_unlocked(out: Path) -> None:
    """Refuse now (before a long computation) when another live process holds ``out``."""
    if os.path.realpath(out) in _HELD or not lock_path(Path(out)).exists():
        return
    FolderLock(Path(out)).acquire().release()


def release_output(out: Path) -> None:
    lock = _HELD.pop(os.path.realpath(out), None)
    if lock is not None:
        lock.release()


def _mark_pid(name: str) -> int | None:
    """The PID in a temporary's name ``.NAME.tmp-PID`` / ``.NAME.old-PID`` (None if absent)."""
    tail = name.rsplit("-", 1)[-1]
    return int(tail) if tail.isdigit() else None


def clean_stale(out: Path) -> None:
    """Remove the temporaries that dead processes left beside ``out`` (a live process's
    temporaries are its work in progress and are kept)."""
    out = Path(out)
    if not out.parent.is_dir():
        return
    for mark in (TMP_MARK, OLD_MARK):
        for stale in out.parent.glob(f".{out.name}{mark}*"):
            _remove_if_dead(stale)


def clean_dead_temporaries(root: Path) -> list[Path]:
    """Remove every ``.*.tmp-PID`` / ``.*.old-PID`` under ``root`` whose process is gone."""
    removed = []
    for mark in (TMP_MARK, OLD_MARK):
        for stale in sorted(Path(root).rglob(f".*{mark}*")):
            if _remove_if_dead(stale):
                removed.append(stale)
    return removed


def _remove_if_dead(stale: Path) -> bool:
    pid = _mark_pid(stale.name)
    if pid is not None and (pid == os.getpid() or pid_alive(pid)):
        return False
    if stale.is_dir() and not stale.is_symlink():
        shutil.rmtree(stale, ignore_errors=True)
    elif stale.exists() or stale.is_symlink():
        stale.unlink(missing_ok=True)
    return True
