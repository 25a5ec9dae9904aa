"""One API process per database. Two APIs on one file would each take the other's runs for a previous process's
(``services.bus_events.reconcile`` fails the runs a starting API finds running without a worker of its own bus to
report them) and both dispatch its queue: an API claims its database for as long as it lives.

The claim is an exclusive ``flock`` on ``<database>.owner`` beside the file, which names the process holding it (its
pid and URL): the kernel drops it when the process ends, however it ends (SIGKILL too), so a stale file never blocks
a restart. The descriptor is not inherited by the processes an API starts (Python opens it close-on-exec, and the
learners are started by a fork server that is itself a fresh interpreter).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from pathlib import Path

from services.store.database import StoreError

OWNER_SUFFIX = ".owner"
"""The claim's file: the database's name with this appended."""


class DatabaseInUse(StoreError):  # noqa: N818 (reads as what happened)
    """Another live process holds the database (``owner``: what it wrote, its pid and URL)."""

    def __init__(self, path: Path, owner: str) -> None:
        super().__init__(
            f"the database {path} is in use by another API ({owner or 'a live process'}): stop it, or give this one "
            "a database of its own (--db, CONTACT_SKILLS_DB)"
        )
        self.path, self.owner = path, owner


def _owner_file(path: Path) -> Path:
    return path.with_name(path.name + OWNER_SUFFIX)


@contextlib.contextmanager
def claimed_database(path: Path, owner: str) -> Iterator[None]:
    """Hold the database at ``path`` for this process while the block runs, writing ``owner`` (its pid and URL) into
    the claim (nothing to hold for an in-memory database, which no other process can open). :class:`DatabaseInUse`
    naming the holder if another live process holds it."""
    if str(path) == ":memory:":
        yield
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    descriptor = os.open(_owner_file(path), os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.read(descriptor, 4096).decode(errors="replace").strip()
            raise DatabaseInUse(path, holder) from None
        os.ftruncate(descriptor, 0)
        os.write(descriptor, owner.encode())
        yield
    finally:
        os.close(descriptor)  # the kernel drops the lock with it


def database_owner(path: Path) -> str | None:
    """What the live process holding the database at ``path`` wrote (its pid and URL), or None when none holds it;
    looks without claiming (``contact-skills up`` asks before it starts anything)."""
    try:
        descriptor = os.open(_owner_file(path), os.O_RDONLY)
    except OSError:  # no claim was ever made here (or it cannot be read: the API's own claim will say why)
        return None
    try:
        fcntl.flock(descriptor, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return os.read(descriptor, 4096).decode(errors="replace").strip() or "a live process"
    finally:
        os.close(descriptor)
    return None
