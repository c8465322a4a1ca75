"""The harnesses' loopback ports (companion.app.loopback) come from below the kernel's ephemeral
range, where no other process's outgoing socket can take them between the check and the bind."""

from __future__ import annotations

import socket

from companion.app.loopback import ephemeral_low, free_blocks, free_ports


def test_ports_are_free_below_the_ephemeral_range_for_tcp_and_udp() -> None:
    low = ephemeral_low()
    ports = free_ports(8)
    assert len(set(ports)) == 8 and all(p < low for p in ports), (ports, low)
    for port in ports:
        for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM):
            with socket.socket(socket.AF_INET, kind) as s:
                s.bind(("127.0.0.1", port))


def test_blocks_are_whole_spaced_and_skip_a_taken_port() -> None:
    first = free_blocks(1, width=6)[0]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as taken:
        taken.bind(("127.0.0.1", first + 3))  # the block is no longer whole
        bases = free_blocks(5, width=6)
        for base in bases:  # every port of every block binds while the taken one is held
            for port in range(base, base + 6):
                with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
                    s.bind(("127.0.0.1", port))
    assert first not in bases
    assert all(b % 10 == 0 and b + 5 < ephemeral_low() for b in bases), bases
    assert len(set(bases)) == 5
