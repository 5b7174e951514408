"""The request-rate limits of one coordinator, and who a request is counted as.

Joins are limited per client address and in total; wrong pairing codes per address and in
total (the code space's budget: 28^6 codes, so a few hundred wrong guesses a minute from
everyone together leave a live code safe for its two minutes); wrong admin tokens per
address. A right QR link (its long key) is never limited, so a worker behind an address a
guesser shares still pairs. Wrong codes are counted in the database, across every replica
(`coord/db/shared_limits.py`); the others in this replica's memory. See docs/security.md.
"""

from __future__ import annotations

from dataclasses import dataclass

from starlette.requests import HTTPConnection

from crowdteleop.coord.db.shared_limits import SharedWindowLimiter
from crowdteleop.coord.db.store import Store
from crowdteleop.coord.guard.clients import ProxyTrust, client_key
from crowdteleop.coord.guard.errors import ApiError
from crowdteleop.coord.guard.limits import WindowLimiter, retry_after
from crowdteleop.coord.service.config import CoordConfig
from crowdteleop.coord.service.metrics import CoordMetrics, Refusal

TOTAL = "all"


@dataclass
class Guards:
    trust: ProxyTrust
    metrics: CoordMetrics
    joins_per_address: WindowLimiter
    joins_total: WindowLimiter
    pair_failures_per_address: SharedWindowLimiter
    pair_failures_total: SharedWindowLimiter
    admin_failures_per_address: WindowLimiter

    @classmethod
    def of(cls, config: CoordConfig, metrics: CoordMetrics, store: Store) -> Guards:
        admission = config.admission
        return cls(
            trust=ProxyTrust.of(config.trusted_proxies),
            metrics=metrics,
            joins_per_address=WindowLimiter(admission.joins_per_minute_per_address),
            joins_total=WindowLimiter(admission.joins_per_minute),
            pair_failures_per_address=store.limiter(
                "pair_failures_address", config.pair_failures_per_minute
            ),
            pair_failures_total=store.limiter(
                "pair_failures_total", config.pair_failures_per_minute_total
            ),
            admin_failures_per_address=WindowLimiter(config.admin_failures_per_minute),
        )

    def client(self, connection: HTTPConnection) -> str:
        """The address (IPv6: /64) this request is counted under."""
        return client_key(connection, self.trust)

    def _check(self, limiter: WindowLimiter, key: str, reason: Refusal, message: str) -> None:
        """Raise 429 (counted as `reason`) while `key` is over `limiter`'s limit; `message`
        gets the wait in seconds in place of `{wait}`."""
        self._refuse_if_waiting(limiter.wait_s(key), reason, message)

    async def _check_shared(
        self, limiter: SharedWindowLimiter, key: str, reason: Refusal, message: str
    ) -> None:
        self._refuse_if_waiting(await limiter.wait_s(key), reason, message)

    def _refuse_if_waiting(self, wait: float, reason: Refusal, message: str) -> None:
        if wait > 0:
            self.metrics.refused(reason)
            text = message.format(wait=f"{wait:.0f}")
            raise ApiError(429, "rate_limited", text, headers=retry_after(wait))

    def admit_join(self, client: str) -> None:
        """Count one join from `client`, or raise 429 past either join limit."""
        self._check(
            self.joins_per_address,
            client,
            "join_rate_address",
            "Too many joins from your network; please wait {wait} s.",
        )
        self._check(
            self.joins_total,
            TOTAL,
            "join_rate_total",
            "The study is busy with joins; please wait {wait} s.",
        )
        self.joins_per_address.hit(client)
        self.joins_total.hit(TOTAL)

    async def check_pairing(self, client: str) -> None:
        """Raise 429 if `client` (or everyone) has guessed too many wrong codes lately."""
        scan = "or scan the QR code instead (it always works)."
        await self._check_shared(
            self.pair_failures_per_address,
            client,
            "pair_rate_address",
            "Too many wrong codes from your network: try again in {wait} s, " + scan,
        )
        await self._check_shared(
            self.pair_failures_total,
            TOTAL,
            "pair_rate_total",
            "Too many wrong codes lately: try again in {wait} s, " + scan,
        )

    async def pairing_failed(self, client: str) -> None:
        self.metrics.refused("pair_bad_code")
        await self.pair_failures_per_address.hit(client)
        await self.pair_failures_total.hit(TOTAL)

    def check_admin(self, client: str) -> None:
        self._check(
            self.admin_failures_per_address,
            client,
            "admin_rate",
            "Too many wrong admin tokens; wait {wait} s.",
        )

    def admin_failed(self, client: str) -> None:
        self.metrics.refused("admin_bad_token")
        self.admin_failures_per_address.hit(client)
