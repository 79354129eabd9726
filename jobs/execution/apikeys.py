"""API keys of the service: created once, shown once, stored only as a digest.

A key is ``nb_<prefix>_<secret>``. The prefix (public, unique) finds the row;
the SHA-256 digest of the whole key is compared with ``hmac.compare_digest``,
whose time does not depend on where two digests differ. Keys are random
(``secrets``), so a plain digest is enough: there is nothing to brute-force.
An admin key (``apikey create --admin``) may also cancel other keys' jobs.

Dashboard logins are server-side sessions: logging in with a key stores a random
session token's digest with the key's id and an expiry, and the browser's cookie
holds only the token. A stolen cookie is worth one session (it ends at logout, at
expiry, or when the key is revoked), never the key itself.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from datetime import UTC, datetime, timedelta

from sqlalchemy import delete, select

from jobs.record.models import ApiKey, LoginSession
from jobs.record.store import Store

PREFIX_BYTES = 6
SECRET_BYTES = 32


def _digest(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()


def create_api_key(store: Store, name: str, *, admin: bool = False) -> tuple[ApiKey, str]:
    """A new key named ``name``; returns (row, the key — never stored, shown once)."""
    prefix = secrets.token_hex(PREFIX_BYTES)
    key = f"nb_{prefix}_{secrets.token_urlsafe(SECRET_BYTES)}"
    row = ApiKey(name=name, prefix=prefix, digest=_digest(key), admin=admin)
    with store.session(write=True) as session:
        session.add(row)
    return row, key


def verify_api_key(store: Store, key: str | None) -> ApiKey | None:
    """The active key row that ``key`` belongs to, or None."""
    if not key or not key.startswith("nb_") or key.count("_") < 2:
        return None
    prefix = key.split("_", 2)[1]
    with store.session() as session:
        row = session.scalars(select(ApiKey).where(ApiKey.prefix == prefix)).one_or_none()
    candidate = _digest(key)
    expected = row.digest if row is not None else _digest("nb_absent_key")
    matches = hmac.compare_digest(candidate, expected)
    if row is None or not matches or row.revoked_at is not None:
        return None
    return row


def list_api_keys(store: Store) -> list[ApiKey]:
    """Every key, oldest first, revoked ones included (rows hold digests, never keys)."""
    with store.session() as session:
        return list(session.scalars(select(ApiKey).order_by(ApiKey.id)))


def revoke_api_key(store: Store, prefix: str) -> bool:
    with store.session(write=True) as session:
        row = session.scalars(select(ApiKey).where(ApiKey.prefix == prefix)).one_or_none()
        if row is None or row.revoked_at is not None:
            return False
        row.revoked_at = datetime.now(UTC)
        return True


def start_session(store: Store, key: ApiKey, max_age_s: float) -> str:
    """A new dashboard session for ``key`` lasting ``max_age_s``; returns its token
    (only its digest is stored). Expired sessions are removed on the way."""
    token = secrets.token_urlsafe(SECRET_BYTES)
    now = datetime.now(UTC)
    with store.session(write=True) as session:
        session.execute(delete(LoginSession).where(LoginSession.expires_at < now))
        session.add(LoginSession(digest=_digest(token), api_key_id=key.id, created_at=now,
                                 expires_at=now + timedelta(seconds=max_age_s)))
    return token


def session_key(store: Store, token: str | None) -> ApiKey | None:
    """The active key of an unexpired session ``token``, or None."""
    if not token:
        return None
    with store.session() as session:
        row = session.scalars(select(ApiKey).join(
            LoginSession, LoginSession.api_key_id == ApiKey.id).where(
            LoginSession.digest == _digest(token),
            LoginSession.expires_at > datetime.now(UTC))).one_or_none()
    return row if row is not None and row.revoked_at is None else None


def end_session(store: Store, token: str | None) -> None:
    """Forget the session ``token`` (logging out); unknown tokens are ignored."""
    if token:
        with store.session(write=True) as session:
            session.execute(delete(LoginSession).where(LoginSession.digest == _digest(token)))
