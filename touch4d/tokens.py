"""Random tokens for links (128 bits, URL-safe) and the rule a token of a user's own must meet: one
place for the study's links, the page's and the lesson's, and the recruitment's open link."""
from __future__ import annotations

import re
import secrets

TOKEN_BYTES = 16                                  # 128 bits
MIN_TOKEN_CHARS = 22                              # base64url characters carrying 128 bits (6 bits each)
TOKEN_CHARS = re.compile(r"[A-Za-z0-9_-]+")       # what secrets.token_urlsafe gives, safe in a URL


def new_token() -> str:
    """A random URL-safe token (128 bits)."""
    return secrets.token_urlsafe(TOKEN_BYTES)


def check_token(token: str) -> str | None:
    """Why a token of a user's own is unfit (None: fit): 128 bits at least, URL-safe characters."""
    if not TOKEN_CHARS.fullmatch(token):
        return "only the characters A-Z a-z 0-9 _ - (as `python -c 'import secrets; print(secrets.token_urlsafe(16))'` gives)"
    if len(token) < MIN_TOKEN_CHARS:
        return f"at least {MIN_TOKEN_CHARS} characters (128 bits), got {len(token)}"
    return None
