"""Bearer tokens with roles (the paper's attacker model).

Roles:

* ``receiver`` — may post frame reports, only as its own ``receiver_id``,
  and read the list of enrolled transmitters (to filter what it sends);
* ``viewer`` — may read everything (site, estimates, health, live stream);
* ``admin`` — everything a viewer may, and change the receiver and pattern
  databases. The attacker model assumes nobody else can.

A token is 32 random bytes (``secrets.token_urlsafe``) prefixed ``rp_``; the
database stores only its SHA-256. A fast hash is enough here because the
token is random with 256 bits of entropy (unlike a password, it cannot be
guessed from a dictionary); lookups compare hashes with an index.
"""

from __future__ import annotations

import hashlib
import secrets
from dataclasses import dataclass

from radiopose.errors import InputError
from radiopose.ids import receiver_id_problem

ROLES = ("admin", "receiver", "viewer")
READ_ROLES = frozenset({"viewer", "admin"})
TOKEN_PREFIX = "rp_"


@dataclass(frozen=True)
class Principal:
    """Who is calling: role and, for receiver tokens, the receiver id."""

    role: str
    receiver_id: str | None = None


def hash_token(token: str) -> str:
    """SHA-256 hex of a token's UTF-8 bytes."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def new_token() -> str:
    """A fresh random bearer token."""
    return TOKEN_PREFIX + secrets.token_urlsafe(32)


def check_role(role: str, receiver_id: str | None) -> None:
    """Validate a role and receiver pairing for ``token create``.

    Raises
    ------
    InputError
        Unknown role, a receiver token without ``--receiver`` or another role with it.
    """
    if role not in ROLES:
        raise InputError(f"--role must be one of {', '.join(ROLES)}, got {role!r}")
    if role == "receiver" and not receiver_id:
        raise InputError("--role receiver needs --receiver ID (the receiver it may post as)")
    if role != "receiver" and receiver_id:
        raise InputError(f"--receiver applies to --role receiver only, not {role!r}")
    if receiver_id is not None and (problem := receiver_id_problem(receiver_id)) is not None:
        raise InputError(f"--receiver: {problem}")


def create_token(db: object, role: str, receiver_id: str | None = None) -> str:
    """Create, store (hashed) and return a new token for ``role``."""
    check_role(role, receiver_id)
    token = new_token()
    db.add_token(hash_token(token), role, receiver_id)  # type: ignore[attr-defined]
    return token
