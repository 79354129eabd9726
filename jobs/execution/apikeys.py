"""API keys of the service: created once, shown once, stored only as a digest.

A key is ``nb_<prefix>_<secret>``. The prefix (public, unique) finds the row;
the SHA-256 digest of the whole key is compared with ``hmac.compare_digest``,
whose time does not depend on where two digests differ. Keys are random
(``secrets``), so a plain digest is enough: there is nothing to brute-force.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from datetime import UTC, datetime

from sqlalchemy import select

from jobs.record.models import ApiKey
from jobs.record.store import Store

PREFIX_BYTES = 6
SECRET_BYTES = 32


def _digest(key: str) -> str:
    return hashlib.sha256(key.encode()).hexdigest()


def create_api_key(store: Store, name: str) -> tuple[ApiKey, str]:
    """A new key named ``name``; returns (row, the key — never stored, shown once)."""
    prefix = secrets.token_hex(PREFIX_BYTES)
    key = f"nb_{prefix}_{secrets.token_urlsafe(SECRET_BYTES)}"
    row = ApiKey(name=name, prefix=prefix, digest=_digest(key))
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


def revoke_api_key(store: Store, prefix: str) -> bool:
    with store.session(write=True) as session:
        row = session.scalars(select(ApiKey).where(ApiKey.prefix == prefix)).one_or_none()
        if row is None or row.revoked_at is not None:
            return False
        row.revoked_at = datetime.now(UTC)
        return True
