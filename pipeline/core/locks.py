"""Locks on output and run folders, and the temporaries of dead processes.

A folder is written by one process at a time: :class:`FolderLock` holds an exclusive
``flock`` on ``.NAME.lock`` beside the folder, with the holder's PID in it. The kernel drops
the lock when its process dies (SIGKILL included), so a stale lock file is taken over by
the next process. Temporaries are folders named ``.NAME.tmp-PID`` / ``.NAME.old-PID``
holding a marker file signed ``qsls temporary PID`` (:data:`TEMP_MARKER`): one whose
process is gone is removed by the next writer (a live process's are its work in progress).
A name alone is never enough: a user's ``.env.old-prod`` or ``.draft.tmp-123`` is never
touched.
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import fcntl
import os
import shutil
from collections.abc import Iterable
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


FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
"""The errors of a full disk (or quota, or file size limit)."""


def full_message(exc: OSError, target: Path | None = None) -> str:
    """One line for a write that found the disk full."""
    where = f" {exc.filename}" if exc.filename else (f" {target}" if target else "")
    return (
        f"cannot write{where}: {exc.strerror or 'no space left on device'}; nothing partial "
        "was kept: free some space (or choose an --out on another disk) and run again"
    )


def unwritable(target: Path, exc: OSError, what: str = "output") -> UnwritableError:
    """One line for an output location that cannot be written: which folder, and why."""
    where = Path(exc.filename).parent if exc.filename else Path(target).parent
    why = exc.strerror or type(exc).__name__
    if exc.errno in FULL:
        return UnwritableError(full_message(exc, target))
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
        try:
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
        except OSError as exc:  # a full disk: no empty lock file is left behind
            with contextlib.suppress(OSError):
                self.path.unlink()
            os.close(fd)
            raise unwritable(self.target, OSError(exc.errno, exc.strerror, str(self.path)),
                             self.what) from None  # fmt: skip
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
    if lock is None:  # held through a symlink that publish has since replaced
        key = next((k for k, v in _HELD.items() if v.target == Path(out)), None)
        lock = _HELD.pop(key) if key is not None else None
    if lock is not None:
        lock.release()


TEMP_MARKER = ".qsls-temporary"
"""The file inside every temporary folder qsls creates: ``qsls temporary PID``. Only a
folder holding it (with the PID of its name) is ever removed as a dead process's temporary."""
_SIGNATURE = "qsls temporary"


def _mark_pid(name: str) -> int | None:
    """The PID in a temporary's name ``.NAME.tmp-PID`` / ``.NAME.old-PID`` (None if absent)."""
    tail = name.rsplit("-", 1)[-1]
    return int(tail) if tail.isdigit() else None


def temporary_name(target: Path, mark: str = TMP_MARK, pid: int | None = None) -> Path:
    """``.NAME.tmp-PID`` (or ``.old-PID``) beside ``target``: this process's temporary."""
    target = Path(target)
    return target.with_name(f".{target.name}{mark}{os.getpid() if pid is None else pid}")


def mark_temporary(folder: Path) -> None:
    """Sign ``folder`` as a qsls temporary of this process (see :data:`TEMP_MARKER`)."""
    (Path(folder) / TEMP_MARKER).write_text(f"{_SIGNATURE} {os.getpid()}\n")


def is_temporary(path: Path) -> bool:
    """Whether ``path`` is a temporary qsls created: a real folder named ``.NAME.tmp-PID`` /
    ``.NAME.old-PID`` holding the marker signed with that PID. Nothing else (a user's
    ``.env.old-prod``, a file, a symlink) ever counts, whatever its name."""
    path = Path(path)
    pid = _mark_pid(path.name)
    if pid is None or not path.name.startswith(".") or path.is_symlink() or not path.is_dir():
        return False
    if TMP_MARK not in path.name and OLD_MARK not in path.name:
        return False
    marker = path / TEMP_MARKER
    if marker.is_symlink() or not marker.is_file():
        return False
    try:
        with open(marker, "rb") as fh:
            text = fh.read(64).decode("ascii", "replace").strip()
    except OSError:
        return False
    return text == f"{_SIGNATURE} {pid}"


def make_temporary(target: Path, mark: str = TMP_MARK) -> Path:
    """Create and sign this process's temporary folder beside ``target`` (its parent must
    exist). A leftover of ours is replaced; anything else in the way is refused, not removed."""
    tmp = temporary_name(target, mark)
    if tmp.exists() or tmp.is_symlink():
        if not is_temporary(tmp):
            raise UnwritableError(
                f"{tmp} is in the way and was not written by qsls; move it away and retry"
            )
        shutil.rmtree(tmp)
    try:
        tmp.mkdir()
        mark_temporary(tmp)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise unwritable(target, exc) from None
    return tmp


def clean_stale(out: Path) -> None:
    """Remove the temporaries that dead qsls processes left beside ``out`` (signed folders
    only, :func:`is_temporary`; a live process's temporaries are its work in progress)."""
    out = Path(out)
    if not out.parent.is_dir():
        return
    for mark in (TMP_MARK, OLD_MARK):
        for stale in out.parent.glob(f".{out.name}{mark}*"):
            _remove_if_dead(stale)


def clean_dead_temporaries(folders: Iterable[Path]) -> list[Path]:
    """Remove the temporaries of dead qsls processes directly in ``folders`` (the levels a
    run writes: the run folder and its stage folders' parents; never deeper, never a
    folder or file qsls did not sign)."""
    removed = []
    for folder in dict.fromkeys(Path(f) for f in folders):
        if folder.is_symlink() or not folder.is_dir():
            continue
        for mark in (TMP_MARK, OLD_MARK):
            for stale in sorted(folder.glob(f".*{mark}*")):
                if _remove_if_dead(stale):
                    removed.append(stale)
    return removed


def _remove_if_dead(stale: Path) -> bool:
    if not is_temporary(stale):
        return False
    pid = _mark_pid(stale.name)
    if pid is not None and (pid == os.getpid() or pid_alive(pid)):
        return False
    shutil.rmtree(stale, ignore_errors=True)
    return True
