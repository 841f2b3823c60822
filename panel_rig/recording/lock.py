"""The advisory lock of a bag directory: held by its writer (or a running `bag recover`) for its whole life.

The lock is an exclusive `flock` on `<bag>/.panel_rig.lock`, whose text is "<pid> <role>". The OS releases it
when the process ends, even by SIGKILL, so only a HELD lock counts: a lock file left by a killed recorder
blocks nothing (`bag recover` takes it over and removes it). The file appears already locked (it is written
and locked under a temporary name, then linked into place) and is removed at release, so a finished bag holds
only metadata.yaml and its .mcap.
"""

from __future__ import annotations

import errno
import fcntl
import os
import secrets
from dataclasses import dataclass
from pathlib import Path

from panel_rig.recording.errors import BagInUseError

LOCK_FILE = ".panel_rig.lock"
ROLES = {"record": "being recorded", "recover": "being recovered"}


@dataclass(frozen=True)
class LockHolder:
    """Who holds a bag's lock: process id (None if unreadable) and role ("record", "recover")."""

    pid: int | None
    role: str

    def describe(self) -> str:
        """`being recorded (by PID 1234)`."""
        text = ROLES.get(self.role, "in use")
        return f"{text} (by PID {self.pid})" if self.pid is not None else text


def _read_holder(fd: int) -> LockHolder:
    try:
        words = os.pread(fd, 64, 0).decode("ascii", "replace").split()
    except OSError:
        words = []
    pid = int(words[0]) if words and words[0].isdigit() else None
    return LockHolder(pid, words[1] if len(words) > 1 else "")


def lock_holder(bag_dir: Path) -> LockHolder | None:
    """Who holds `bag_dir`'s lock, or None if nobody does (no lock file, or a stale one). Creates nothing."""
    try:
        fd = os.open(Path(bag_dir) / LOCK_FILE, os.O_RDONLY)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)  # conflicts with the holder's exclusive lock
    except OSError as exc:
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
            return _read_holder(fd)
        return None
    finally:
        os.close(fd)  # also releases our shared lock
    return None


class BagLock:
    """The exclusive lock of `bag_dir` for this process; raises BagInUseError if another process holds it.

    A stale lock file (its process died) is taken over. `release()` removes the lock file and unlocks;
    the OS unlocks if the process dies first."""

    def __init__(self, bag_dir: Path, role: str) -> None:
        self.path = Path(bag_dir) / LOCK_FILE
        self._fd: int | None = None
        tmp = self.path.with_name(f"{LOCK_FILE}.{os.getpid()}.{secrets.token_hex(4)}")
        fd = os.open(tmp, os.O_RDWR | os.O_CREAT | os.O_EXCL, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)  # a new inode: nobody else can hold it
            os.write(fd, f"{os.getpid()} {role}\n".encode("ascii"))
            self._install(tmp, fd)
        except BaseException:
            os.close(fd)
            raise
        finally:
            tmp.unlink(missing_ok=True)
        self._fd = fd

    def _install(self, tmp: Path, fd: int) -> None:
        """Put our locked `tmp` at the lock path: link it, or replace a stale lock file."""
        for _ in range(100):
            try:
                os.link(tmp, self.path)
                return
            except FileExistsError:
                pass
            try:
                old = os.open(self.path, os.O_RDONLY)
            except FileNotFoundError:
                continue  # released meanwhile: link again
            try:
                try:
                    fcntl.flock(old, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError as exc:
                    if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN):
                        holder = _read_holder(old)
                        raise BagInUseError(f"{self.path.parent} is {holder.describe()}", holder.pid) from None
                    raise
                if _same_file(self.path, old):  # stale and still in place: replace it while we hold it
                    os.replace(tmp, self.path)
                    return
            finally:
                os.close(old)
        raise BagInUseError(f"{self.path.parent}: cannot take the lock {self.path}")

    @property
    def held(self) -> bool:
        return self._fd is not None

    def release(self) -> None:
        """Remove the lock file (if it is still ours) and unlock. Idempotent."""
        fd, self._fd = self._fd, None
        if fd is None:
            return
        try:
            if _same_file(self.path, fd):
                self.path.unlink(missing_ok=True)
        except OSError:
            pass
        finally:
            os.close(fd)


def _same_file(path: Path, fd: int) -> bool:
    try:
        st, own = os.stat(path), os.fstat(fd)
    except OSError:
        return False
    return (st.st_dev, st.st_ino) == (own.st_dev, own.st_ino)
