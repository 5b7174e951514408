"""Which client a request comes from, as the limits count it (docs/security.md).

The address is the TCP peer's, never a header's, unless that peer is a reverse proxy the
operator named in `CoordConfig.trusted_proxies`: then it is the right-most address of
`X-Forwarded-For` that is not itself a trusted proxy (the left part is whatever the client
wrote). IPv6 clients are counted per /64, the block one subscriber usually holds, so a
single host cannot walk through 2^64 addresses of its own.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable
from dataclasses import dataclass

from starlette.requests import HTTPConnection

Network = ipaddress.IPv4Network | ipaddress.IPv6Network
IPV6_PREFIX = 64


@dataclass(frozen=True)
class ProxyTrust:
    """The reverse proxies whose `X-Forwarded-For` is believed (none by default)."""

    networks: tuple[Network, ...] = ()

    @classmethod
    def of(cls, entries: Iterable[str]) -> ProxyTrust:
        """From addresses or CIDR networks; a malformed entry raises ValueError at start."""
        return cls(tuple(ipaddress.ip_network(entry.strip(), strict=False) for entry in entries))

    def trusts(self, address: str) -> bool:
        parsed = _parse(address)
        return parsed is not None and any(parsed in net for net in self.networks)


def _parse(address: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        parsed = ipaddress.ip_address(address.strip().strip("[]"))
    except ValueError:
        return None
    if isinstance(parsed, ipaddress.IPv6Address) and parsed.ipv4_mapped is not None:
        return parsed.ipv4_mapped
    return parsed


def address_key(address: str) -> str:
    """What one client is counted under: the IPv4 address, or the IPv6 /64 around it."""
    parsed = _parse(address)
    if parsed is None:
        return address[:64] or "unknown"  # test clients ("testclient") and unix sockets
    if isinstance(parsed, ipaddress.IPv6Address):
        return str(ipaddress.IPv6Network((parsed, IPV6_PREFIX), strict=False))
    return str(parsed)


def client_address(connection: HTTPConnection, trust: ProxyTrust) -> str:
    """The client's address: the peer's, or through trusted proxies, the one they saw."""
    peer = connection.client.host if connection.client else "unknown"
    if not trust.networks or not trust.trusts(peer):
        return peer
    forwarded = ",".join(connection.headers.getlist("x-forwarded-for"))
    hops = [hop.strip() for hop in forwarded.split(",") if hop.strip()]
    for hop in reversed(hops):
        if _parse(hop) is None:
            return peer  # a garbled chain: count the proxy itself rather than guess
        if not trust.trusts(hop):
            return hop
    return hops[0] if hops else peer


def client_key(connection: HTTPConnection, trust: ProxyTrust) -> str:
    return address_key(client_address(connection, trust))
