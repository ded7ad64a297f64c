"""Larger kernel receive buffers on this process's UDP sockets (the middleware's). No ROS import.

Under ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, rmw_fastrtps replaces Fast DDS's built-in
transports with a UDPv4 transport of its own, whose sockets get the OS default receive buffer
(net.core.rmem_default, 212,992 B here); the XML profile's socket buffer sizes apply to the
built-in transports only, and no ROS or rmw setting reaches these sockets. When the
process's middleware thread falls behind on a loaded machine, a 1 kHz recording of two topics
can fill that buffer, and the kernel then drops the datagrams: a publisher keeping 10 samples
cannot resend them, so a run of messages never reaches the bag
(measured: /proc/net/snmp's Udp RcvbufErrors rose by 196 in a round of tests that lost 96
joint states and as many positions, while a second subscriber in another process got every
message). `enlarge_udp_receive_buffers` asks the kernel for more on every UDP socket the
process holds, as any program may up to net.core.rmem_max.
"""

import os
import socket
import stat
from pathlib import Path

RMEM_MAX = Path('/proc/sys/net/core/rmem_max')
"""The largest receive buffer (bytes) an unprivileged SO_RCVBUF request may get."""


def rmem_max(default: int = 4 * 1024 * 1024) -> int:
    """net.core.rmem_max in bytes, or `default` where /proc does not say (not Linux)."""
    try:
        return int(RMEM_MAX.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return default


def enlarge_udp_receive_buffers(size: int, fd_dir: Path = Path('/proc/self/fd')
                                ) -> tuple[int, int]:
    """Ask for a `size`-byte receive buffer (SO_RCVBUF) on every UDP socket this process has
    open; never shrink one. Returns (sockets found, smallest buffer after them, in bytes as
    the kernel reports it: it doubles the size it grants, at most net.core.rmem_max, for its
    own bookkeeping); (0, 0) where the process's descriptors cannot be listed."""
    try:
        descriptors = [int(name) for name in os.listdir(fd_dir)]
    except OSError:
        return 0, 0
    found, smallest = 0, 0
    for fd in descriptors:
        try:
            if not stat.S_ISSOCK(os.fstat(fd).st_mode):
                continue
            # A duplicate of the descriptor: closing it leaves the middleware's socket open.
            duplicate = os.dup(fd)
        except OSError:
            continue
        try:
            sock = socket.socket(fileno=duplicate)
        except OSError:  # a family Python does not know
            os.close(duplicate)
            continue
        with sock:
            if sock.type != socket.SOCK_DGRAM or sock.family not in (socket.AF_INET,
                                                                   socket.AF_INET6):
                continue
            try:
                if sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) < size:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)
                granted = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
            except OSError:
                continue
            found += 1
            smallest = granted if found == 1 else min(smallest, granted)
    return found, smallest
