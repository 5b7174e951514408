"""WebRTC peering (crowdteleop.teleop.peering): offers' mDNS candidates are dropped."""

from __future__ import annotations


def test_mdns_candidates_are_dropped_from_offers_and_nothing_else():
    from crowdteleop.teleop.peering import without_mdns_candidates

    offer = "\r\n".join(
        [
            "v=0",
            "a=candidate:1 1 udp 2113937151 3f1c7a2e-1111-4c1d.local 54321 typ host",
            "a=candidate:2 1 udp 2113939711 192.168.1.20 54322 typ host",
            "a=candidate:3 1 udp 1677729535 203.0.113.7 54323 typ srflx raddr 0.0.0.0 rport 0",
            "a=end-of-candidates",
            "",
        ]
    )
    kept = without_mdns_candidates(offer)
    assert ".local" not in kept
    assert "192.168.1.20" in kept and "203.0.113.7" in kept and "a=end-of-candidates" in kept
