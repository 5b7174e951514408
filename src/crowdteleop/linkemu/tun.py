"""TUN devices inside network namespaces, opened by one process that forwards between them."""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import struct
import subprocess
from collections.abc import Iterator

_TUNSETIFF = 0x400454CA
_IFF_TUN = 0x0001
_IFF_NO_PI = 0x1000
_CLONE_NEWNET = 0x40000000


def _setns(fd: int) -> None:
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.setns(fd, _CLONE_NEWNET) != 0:
        errno = ctypes.get_errno()
        raise OSError(errno, f"setns: {os.strerror(errno)}")


@contextlib.contextmanager
def inside(namespace: str) -> Iterator[None]:
    """This thread in the named network namespace (`ip netns add`), then back."""
    home = os.open("/proc/thread-self/ns/net", os.O_RDONLY)
    target = os.open(f"/run/netns/{namespace}", os.O_RDONLY)
    try:
        _setns(target)
        yield
    finally:
        _setns(home)
        os.close(target)
        os.close(home)


def open_tun(namespace: str, name: str) -> int:
    """A non-blocking TUN device `name` (raw IP packets) created in `namespace`: it lives as
    long as the returned descriptor stays open."""
    with inside(namespace):
        fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
        try:
            fcntl.ioctl(fd, _TUNSETIFF, struct.pack("16sH", name.encode(), _IFF_TUN | _IFF_NO_PI))
        except OSError:
            os.close(fd)
            raise
    return fd


def address(namespace: str, device: str, local: str, peer: str, mtu: int = 1500) -> None:
    """A point-to-point address on `device`, the device up, and the namespace's loopback."""
    for command in (
        ["ip", "-n", namespace, "link", "set", "lo", "up"],
        ["ip", "-n", namespace, "addr", "add", local, "peer", peer, "dev", device],
        ["ip", "-n", namespace, "link", "set", device, "mtu", str(mtu), "up"],
    ):
        subprocess.run(command, check=True, capture_output=True)
