"""Private ROS domains: a run never takes a domain another run on this host has claimed or has a node in."""

from __future__ import annotations

import errno
import socket

from panel_rig.domains import TEST_DOMAINS, claim_domain_id, discovery_port, domain_in_use, lock_path


def test_a_claimed_domain_is_not_claimed_twice_and_is_free_again_after_release() -> None:
    """Two suite runs side by side drew their domains at random from the same 99: a test module could share its
    graph with the other run's node; a domain another claim holds is skipped (only when none is free is one given
    unlocked)."""
    held = claim_domain_id(*TEST_DOMAINS)
    d = held.domain_id
    try:
        assert held._fd is not None
        other = claim_domain_id(d, d)  # the only candidate is held: given unlocked, as a last resort
        assert other.domain_id == d and other._fd is None
    finally:
        held.release()
    again = claim_domain_id(d, d)
    try:
        assert again._fd is not None  # released: free to claim
    finally:
        again.release()


def test_a_domain_with_a_participant_on_this_host_is_skipped() -> None:
    """A DDS participant binds its domain's discovery port (7400 + 250 d + 10 for the first one): such a domain is
    taken whoever holds it (another user's node, a program that does not lock)."""
    held = claim_domain_id(*TEST_DOMAINS)  # a domain nobody else uses while this test binds its port
    d = held.domain_id
    try:
        assert not domain_in_use(d)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("0.0.0.0", discovery_port(d, 1)))  # as Fast DDS's second participant in domain d
            assert domain_in_use(d)
            held.release()
            assert claim_domain_id(d, d)._fd is None  # in use, though unlocked: not claimed
        assert not domain_in_use(d)
    finally:
        held.release()


def test_a_port_the_host_refuses_for_another_reason_leaves_the_lock_file_to_decide(monkeypatch) -> None:
    """A bind refused with anything but EADDRINUSE (no IPv4, a sandbox) raised out of the claim: a program failed
    with a traceback before it started its node. Such a port tells nothing; the lock file still keeps claims apart."""

    def refuse(self, address):
        raise OSError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(socket.socket, "bind", refuse)
    lo, hi = TEST_DOMAINS
    assert not domain_in_use(lo)
    held = claim_domain_id(lo, hi)
    try:
        assert held._fd is not None
        assert claim_domain_id(held.domain_id, held.domain_id)._fd is None
    finally:
        held.release()


def test_a_released_claim_removes_its_lock_file_and_a_waiting_claim_takes_a_new_one() -> None:
    """Released claims left their lock files in /tmp (one per domain ever used: ~100 after a suite run). A
    released claim removes its file; a claim that opened the old file before the removal sees it is gone and
    locks a new one, so two processes never each hold a lock on a different file of the same domain."""
    import fcntl
    import os

    held = claim_domain_id(*TEST_DOMAINS)
    d, path = held.domain_id, lock_path(held.domain_id)
    assert path.exists()
    late = os.open(path, os.O_RDWR)  # another process opened the file, and waits for the lock
    try:
        held.release()
        assert not path.exists()
        fcntl.flock(late, fcntl.LOCK_EX | fcntl.LOCK_NB)  # it gets the lock, of a file no longer in /tmp
        again = claim_domain_id(d, d)  # and a claim now locks a new file: the removed one holds nobody off
        try:
            assert again._fd is not None and path.exists()
        finally:
            again.release()
    finally:
        os.close(late)
    assert not path.exists()


def test_a_claim_whose_file_was_removed_before_it_locked_it_locks_a_new_one(monkeypatch) -> None:
    """Between a claim's open and its lock the holder may release (remove) the file: the claim then holds a lock on
    a file no other process can find. It checks, and locks a file at the path instead."""
    import fcntl

    from panel_rig import domains

    d = claim_domain_id(*TEST_DOMAINS)
    d.release()
    path, real_flock, calls = lock_path(d.domain_id), fcntl.flock, []

    def holder_releases_first(fd: int, op: int) -> None:
        calls.append(fd)
        if len(calls) == 1:
            path.unlink()  # the holder's release, just before this claim's lock
        real_flock(fd, op)

    monkeypatch.setattr(domains.fcntl, "flock", holder_releases_first)
    claim = claim_domain_id(d.domain_id, d.domain_id)
    try:
        assert len(calls) == 2 and claim._fd is not None and domains._same_file(claim._fd, path)
    finally:
        claim.release()
