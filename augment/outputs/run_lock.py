"""One writer per run folder: ``_LOCK``, held with ``flock`` for the life of the run.

The kernel drops a ``flock`` when its process dies (SIGKILL included), so a lock is never left held by a dead
run; the JSON inside (pid, host, since) only names the holder in the refusal. A writer that ends normally
removes the file; a file found with no ``flock`` on it was left by a run that died, and is taken over with a
warning. Needs a file system with ``flock`` (local disks; NFSv4 and most cluster file systems emulate it).
"""

from __future__ import annotations

import json
import logging
import os
import socket
import time
from pathlib import Path
from types import TracebackType

from motionaug.augment.io import fsync_dir
from motionaug.schemas.errors import MotionDataError

LOCK_FILE = "_LOCK"
LOG = logging.getLogger(__name__)
_HELD: set[Path] = set()  # run folders this process holds the lock of


def holder_text(record: dict) -> str:
    """``pid 123 on host-a since 2026-01-02T10:00:00Z`` from a lock file's JSON (whatever part of it is there)."""
    return f"pid {record.get('pid', '?')} on {record.get('host', '?')} since {record.get('since', '?')}"


def _read_holder(fd: int) -> dict | None:
    """The JSON a lock file holds, None when empty; a torn or foreign text reads as an unnamed holder."""
    os.lseek(fd, 0, os.SEEK_SET)
    text = os.read(fd, 4096).decode("utf-8", errors="replace").strip()
    if not text:
        return None
    try:
        record = json.loads(text)
    except ValueError:
        return {}
    return record if isinstance(record, dict) else {}


class RunLock:
    """``with RunLock(root):`` the run folder is this process's until the block ends (normally or not).

    A second taker gets one ``MotionDataError`` naming the holder; ``takeover`` says whose stale lock was taken.
    ``wait_s`` lets a taker that expects the holder to exit soon (a retried job whose stopped driver is still
    shutting down) keep trying that long before it refuses.
    """

    def __init__(self, root: str | Path, wait_s: float = 0.0) -> None:
        self.root = Path(root).resolve()
        self.path = self.root / LOCK_FILE
        self.wait_s = wait_s
        self.fd: int | None = None
        self.takeover: str | None = None

    @staticmethod
    def is_held_here(root: str | Path) -> bool:
        """Whether this process holds the lock of ``root`` (stage code that needs it asks)."""
        return Path(root).resolve() in _HELD

    def acquire(self) -> RunLock:
        import fcntl  # POSIX; imported here so reading a run folder (export, evaluate) works everywhere

        deadline = time.monotonic() + self.wait_s
        while True:
            try:
                self.root.mkdir(parents=True, exist_ok=True)
                fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as err:
                raise MotionDataError(str(self.path), f"cannot create the run lock ({err.strerror})") from None
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = holder_text(_read_holder(fd) or {})
                os.close(fd)
                if time.monotonic() < deadline:
                    time.sleep(0.2)
                    continue
                reason = f"another motionaug run holds this folder ({holder}); wait for it to end or use another --out"
                raise MotionDataError(str(self.root), reason) from None
            except OSError as err:
                os.close(fd)
                raise MotionDataError(str(self.path), f"cannot lock the run folder ({err.strerror})") from None
            if self._same_file(fd):
                break
            os.close(fd)  # the holder released (removed) it between our open and flock: lock the new file
        stale = _read_holder(fd)
        if stale is not None:
            self.takeover = f"took over the lock of a run that is gone ({holder_text(stale)})"
            LOG.warning("%s: %s", self.root, self.takeover)
        record = {"pid": os.getpid(), "host": socket.gethostname(), "since": _utc_now()}
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, (json.dumps(record) + "\n").encode(), 0)
            os.fsync(fd)
            fsync_dir(self.root)
        except OSError as err:
            os.close(fd)
            raise MotionDataError(str(self.path), f"cannot write the run lock ({err.strerror})") from None
        self.fd = fd
        _HELD.add(self.root)
        return self

    def release(self) -> None:
        """Remove the file, then drop the ``flock`` (in that order: a waiting taker re-checks the path)."""
        if self.fd is None:
            return
        _HELD.discard(self.root)
        try:
            self.path.unlink(missing_ok=True)
        finally:
            os.close(self.fd)
            self.fd = None

    def _same_file(self, fd: int) -> bool:
        try:
            return os.stat(self.path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            return False

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, kind: type | None, err: BaseException | None, tb: TracebackType | None) -> None:
        self.release()


def _utc_now() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
