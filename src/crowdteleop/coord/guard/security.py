"""Tokens, bearer parsing, pairing codes, and how strong a given admin token is."""

from __future__ import annotations

import hashlib
import hmac
import math
import secrets
from collections import Counter

# No 0/O, 1/I/L, 5/S, 8/B: a code read off one screen and typed on another survives it.
PAIRING_ALPHABET = "2346789ACDEFGHJKMNPQRTUVWXYZ"
PAIRING_CODE_LENGTH = 6
COMPLETION_ALPHABET = "ABCDEFGHJKLMNPQRSTUVWXYZ23456789"


def new_token() -> str:
    """256 bits from the OS's CSPRNG, URL-safe."""
    return secrets.token_urlsafe(32)


def new_id(prefix: str) -> str:
    return f"{prefix}_{secrets.token_hex(8)}"


def token_hash(token: str) -> str:
    """What the database keeps: a leaked table gives no usable token."""
    return hashlib.sha256(token.encode()).hexdigest()


def same(a: str, b: str) -> bool:
    return hmac.compare_digest(a.encode(), b.encode())


def new_pairing_code() -> str:
    return "".join(secrets.choice(PAIRING_ALPHABET) for _ in range(PAIRING_CODE_LENGTH))


def normalize_pairing_code(code: str) -> str:
    return code.strip().replace(" ", "").replace("-", "").upper()


def new_completion_code() -> str:
    return "".join(secrets.choice(COMPLETION_ALPHABET) for _ in range(10))


def bearer(header: str | None) -> str | None:
    """The token of an ``Authorization: Bearer <token>`` header, or None."""
    if not header:
        return None
    scheme, _, value = header.partition(" ")
    value = value.strip()
    if scheme.lower() != "bearer" or not value or len(value) > 512:
        return None
    return value


ADMIN_TOKEN_MIN_BITS = 128


def estimated_entropy_bits(token: str) -> float:
    """A conservative guess of a token's entropy: its length times the smaller of (a) the
    bits per character its character classes allow and (b) one bit more than the Shannon
    entropy of its own characters. A random 32-character URL-safe token scores ~170; a
    repeated letter, a word pattern or a short token scores far below 128."""
    if not token:
        return 0.0
    classes = [
        (any(c.islower() for c in token), 26),
        (any(c.isupper() for c in token), 26),
        (any(c.isdigit() for c in token), 10),
        (any(not c.isalnum() for c in token), 32),
    ]
    alphabet = sum(size for present, size in classes if present)
    counts = Counter(token)
    shannon = -sum(n / len(token) * math.log2(n / len(token)) for n in counts.values())
    return len(token) * min(math.log2(alphabet), shannon + 1.0)
