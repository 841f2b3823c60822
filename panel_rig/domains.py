"""Private ROS 2 domains on this host: a one-command program (demo, control demo, flutter test) or a test module
runs its node and client in a domain of its own, so two runs side by side never share a graph.

A domain is taken when a DDS participant on this host has bound its discovery port (Fast DDS, the RMW the package
installs: UDP 7400 + 250 d + 10 + 2 i for participant i, the one DDS port in use when discovery is limited to
localhost), or when another of our processes holds the domain's lock file (it has picked the domain but not yet
started its node). :func:`claim_domain_id` skips both and holds the lock for the life of the process, or until
:meth:`DomainClaim.release`.
"""

from __future__ import annotations

import atexit
import errno
import fcntl
import os
import random
import socket
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

#: the domains our one-command programs pick from: 1..101, the ids whose ports stay out of Linux's ephemeral
#: range; the test suite keeps to TEST_DOMAINS, so a demo run beside it never shares its graph
PRIVATE_DOMAINS = (1, 101)
TEST_DOMAINS = (102, 200)
PARTICIPANTS_CHECKED = 4  # participant ids whose discovery port is probed


def discovery_port(domain_id: int, participant: int = 0) -> int:
    """Fast DDS's unicast discovery (metatraffic) port of ``participant`` in ``domain_id`` (the RTPS spec's
    default port mapping: PB 7400, DG 250, PG 2, d1 10)."""
    return 7400 + 250 * domain_id + 10 + 2 * participant


def domain_in_use(domain_id: int) -> bool:
    """Whether a DDS participant on this host has bound one of the domain's first discovery ports. A port the
    host will not let us bind for another reason (no IPv4, a sandbox's policy) tells nothing: not in use, and the
    lock file alone decides."""
    for i in range(PARTICIPANTS_CHECKED):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("0.0.0.0", discovery_port(domain_id, i)))
            except OSError as exc:
                if exc.errno == errno.EADDRINUSE:
                    return True
    return False


@dataclass
class DomainClaim:
    """A domain id this process holds: its lock file stays locked until :meth:`release` or the process ends.
    Released, the file is removed (a suite run left ~100 of them in /tmp)."""

    domain_id: int
    _fd: int | None = field(default=None, repr=False)

    def release(self) -> None:
        if self._fd is not None:
            path = lock_path(self.domain_id)
            # removed while still locked, and only if it is still the file this claim locked: a process that opens
            # the path in between finds, once it has the lock, that its file is gone (:func:`_lock` checks) and
            # retries on a new one
            if _same_file(self._fd, path):
                path.unlink(missing_ok=True)
            os.close(self._fd)  # closing the descriptor drops the lock
            self._fd = None


_HELD: list[DomainClaim] = []  # the claims of private_domain_id(): held until the process ends


def _release_held() -> None:
    while _HELD:
        _HELD.pop().release()


atexit.register(_release_held)


def lock_path(domain_id: int) -> Path:
    """The domain's lock file."""
    return Path(tempfile.gettempdir()) / f"panel_rig_ros_domain_{domain_id}.lock"


def _same_file(fd: int, path: Path) -> bool:
    """Whether ``path`` still names the file open as ``fd``."""
    try:
        on_disk = os.stat(path)
    except FileNotFoundError:
        return False
    held = os.fstat(fd)
    return (held.st_dev, held.st_ino) == (on_disk.st_dev, on_disk.st_ino)


def _lock(domain_id: int) -> int | None:
    """The domain's lock file, locked by this process (its descriptor), or None if another process holds it."""
    path = lock_path(domain_id)
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            return None
        if _same_file(fd, path):
            return fd
        os.close(fd)  # its holder released and removed it while this process waited: a new file


def claim_domain_id(lo: int, hi: int) -> DomainClaim:
    """A random free domain in [lo, hi], locked for this process; when every one is taken, a random one unlocked
    (a program still refuses a graph where another rig answers its commands)."""
    ids = list(range(lo, hi + 1))
    random.shuffle(ids)
    for d in ids:
        if domain_in_use(d):
            continue
        fd = _lock(d)
        if fd is not None:
            return DomainClaim(d, fd)
    return DomainClaim(ids[0])


def private_domain_id() -> int:
    """A free domain in PRIVATE_DOMAINS for a program's node + client pair, held until the program ends (the
    programs also limit discovery to this host)."""
    claim = claim_domain_id(*PRIVATE_DOMAINS)
    _HELD.append(claim)
    return claim.domain_id
