"""The teleop servers' tokens, derived per session from one server secret instead of stored.

The coordinator must present a session's worker token (in every offer it forwards) and hand
out its admin token (the admin API's privileged-bot access), so neither can be a hash. Each is
HMAC-SHA256(secret, purpose + session id): the database holds no usable token, and the secret
lives in a 0600 file under the data folder's `state/`. A lost secret only orphans the tokens of
sessions a previous run left, which the coordinator ends on start anyway.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import logging
import os
import secrets
from pathlib import Path

from crowdteleop.coord.guard.private import PRIVATE_FILE, tighten, write_private

log = logging.getLogger(__name__)

SECRET_BYTES = 32
SESSION_SECRET_FILE = "session.key"  # in the data folder's state/


class SessionSecretError(RuntimeError):
    """The server secret file exists but is not a secret we wrote."""


class SessionKeys:
    """`teleop_token(session_id)` and `teleop_admin_token(session_id)`, from one secret."""

    def __init__(self, secret: bytes) -> None:
        if len(secret) < SECRET_BYTES:
            raise SessionSecretError(f"the session secret needs {SECRET_BYTES} bytes")
        self._secret = secret

    @classmethod
    def load_or_create(cls, path: Path) -> SessionKeys:
        """The secret in `path`, made (0600) if missing. It is written to a private temporary
        file and linked into place, so a concurrent start reads a whole secret or makes it."""
        if not path.exists():
            secret = secrets.token_bytes(SECRET_BYTES)
            staging = write_private(path.with_name(f".{path.name}.{os.getpid()}"), secret.hex())
            try:
                os.link(staging, path)
                log.info("made a new session secret in %s", path)
                return cls(secret)
            except FileExistsError:
                pass  # another start made it first: use theirs
            finally:
                staging.unlink()
        tighten(path, PRIVATE_FILE)
        try:
            return cls(bytes.fromhex(path.read_text(encoding="ascii").strip()))
        except (UnicodeDecodeError, ValueError, SessionSecretError) as exc:
            raise SessionSecretError(
                f"{path} is not a session secret; delete it to make a new one "
                "(sessions a previous run left are ended on start anyway)"
            ) from exc

    def _derive(self, purpose: bytes, session_id: str) -> str:
        digest = hmac.new(self._secret, purpose + b"\0" + session_id.encode(), hashlib.sha256)
        return base64.urlsafe_b64encode(digest.digest()).rstrip(b"=").decode()

    def teleop_token(self, session_id: str) -> str:
        """The session's worker token: what the coordinator puts in every forwarded offer."""
        return self._derive(b"teleop-token", session_id)

    def client_tag(self, client_key: str) -> str:
        """What the database keeps of a client's address: an HMAC, no address."""
        return self._derive(b"client", client_key)

    def teleop_admin_token(self, session_id: str) -> str:
        """The session's admin token: privileged peers, `/telemetry`, `/assign`."""
        return self._derive(b"teleop-admin-token", session_id)
