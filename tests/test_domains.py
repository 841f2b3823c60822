"""Private ROS domains: a run never takes a domain another run on this host has claimed or has a node in."""

from __future__ import annotations

import errno
import socket

from panel_rig.domains import TEST_DOMAINS, claim_domain_id, discovery_port, domain_in_use


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
