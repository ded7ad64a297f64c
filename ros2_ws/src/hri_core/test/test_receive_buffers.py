"""Unit tests of hri_core.receive_buffers: this process's UDP sockets get larger buffers."""

import socket
from pathlib import Path

import pytest

from hri_core.receive_buffers import enlarge_udp_receive_buffers, rmem_max


def receive_buffer(sock: socket.socket) -> int:
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


@pytest.fixture
def sockets():
    opened = {'small': socket.socket(socket.AF_INET, socket.SOCK_DGRAM),
              'tcp': socket.socket(socket.AF_INET, socket.SOCK_STREAM)}
    opened['small'].setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    opened['tcp'].setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    yield opened
    for sock in opened.values():
        sock.close()


def test_udp_sockets_grow_and_other_sockets_stay(sockets):
    size = min(rmem_max(), 1 << 20)
    tcp_before = receive_buffer(sockets['tcp'])
    found, smallest = enlarge_udp_receive_buffers(size)
    assert found >= 1
    # The kernel reports twice what it granted (its bookkeeping overhead included).
    assert receive_buffer(sockets['small']) >= size
    assert smallest >= size
    assert receive_buffer(sockets['tcp']) == tcp_before


def test_a_larger_buffer_is_never_shrunk(sockets):
    sockets['small'].setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 65536)
    before = receive_buffer(sockets['small'])
    enlarge_udp_receive_buffers(8192)
    assert receive_buffer(sockets['small']) == before


def test_no_descriptor_listing_means_nothing_done(tmp_path):
    assert enlarge_udp_receive_buffers(1 << 20, fd_dir=tmp_path / 'missing') == (0, 0)


def test_rmem_max_falls_back_where_proc_does_not_say(monkeypatch, tmp_path):
    monkeypatch.setattr('hri_core.receive_buffers.RMEM_MAX', tmp_path / 'missing')
    assert rmem_max(default=1234) == 1234
    monkeypatch.setattr('hri_core.receive_buffers.RMEM_MAX', Path('/proc/sys/net/core/rmem_max'))
    assert rmem_max() > 0
