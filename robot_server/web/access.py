"""Who may press the web view's buttons: the token its commands need when it binds beyond loopback.

On a loopback address the page is for this machine, and its commands (faults, reset, drives, the
mode: everything that changes the controller) need nothing, unless a token is given: then they need
it. On any other address (``0.0.0.0``, ``::``, a LAN address, a host name) they need a token: the one
given (``--web-token``, :data:`TOKEN_ENV`), or one made at start (:func:`web_token`), which the
command prints once. A page gets the token from its address (``http://host:port/?token=...``, the
URL printed) and offers it when it opens its WebSocket; without the right one the page is read-only
(:meth:`Access.why_read_only` says why) and a command it sends anyway is refused before it reaches
the robot. Tokens are compared in constant time (:func:`hmac.compare_digest`) and never logged.

This protects the web view's buttons only: the simple_message ports have no authentication at all
(docs/deploy.md, "Who can steer a robot").
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from urllib.parse import quote

__all__ = ["TOKEN_ENV", "MIN_TOKEN", "MAX_TOKEN", "Access", "is_loopback", "web_token", "check_token", "token_url"]

#: the environment variable the command reads a token from (when ``--web-token`` is not given)
TOKEN_ENV = "ROBOT_SERVER_WEB_TOKEN"
#: the shortest and longest token accepted (characters)
MIN_TOKEN = 8
MAX_TOKEN = 256
#: random bytes of a token made at start (URL-safe base64: 22 characters)
GENERATED_BYTES = 16


def is_loopback(host: str) -> bool:
    """``host`` is a loopback address (``127.0.0.0/8``, ``::1``) or ``localhost``: only this
    machine reaches what binds it. Any other host, a name included, is not."""
    name = host.strip().strip("[]").lower()
    if name == "localhost":
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False


def check_token(token: str) -> str:
    """``token`` if it can be a web token: printable ASCII without spaces, :data:`MIN_TOKEN` to
    :data:`MAX_TOKEN` characters. Raises ValueError (without repeating the token) otherwise."""
    if not MIN_TOKEN <= len(token) <= MAX_TOKEN:
        raise ValueError(f"a web token is {MIN_TOKEN} to {MAX_TOKEN} characters, not {len(token)}")
    if not all("!" <= c <= "~" for c in token):
        raise ValueError("a web token is printable ASCII without spaces")
    return token


def web_token(host: str, given: str | None) -> tuple[str | None, bool]:
    """The token the web view's commands need on ``host``, and whether it was made here.

    ``given`` (an option's or the environment's value; ``None`` or empty: none given) is checked
    (:func:`check_token`) and used on any host. Without one, a loopback host needs none
    (``(None, False)``) and any other gets a new random token (``(token, True)``): the caller
    prints it once, in the URL of :func:`token_url`."""
    if given is not None and given.strip():
        return check_token(given), False
    if is_loopback(host):
        return None, False
    return secrets.token_urlsafe(GENERATED_BYTES), True


def token_url(url: str, token: str | None) -> str:
    """``url`` (a page's address, with no query) carrying ``token`` for the page to use."""
    return url if token is None else f"{url}?token={quote(token, safe='')}"


class Access:
    """Whether a page may send commands: ``token`` is what they need (``None``: nothing)."""

    def __init__(self, token: str | None) -> None:
        self._token = None if token is None else check_token(token).encode()

    @property
    def required(self) -> bool:
        """Commands need a token."""
        return self._token is not None

    def why_read_only(self, offered: str | None) -> str | None:
        """``None`` when a page that offered ``offered`` (``None``: nothing) may send commands, else
        why it may not (for the page to show, without the token)."""
        if self._token is None:
            return None
        if not offered:
            return "read-only: commands need the web view's token (open the address printed at start, ?token=...)"
        if not hmac.compare_digest(offered.encode("utf-8", "surrogateescape"), self._token):
            return "read-only: the token in this page's address is not this web view's"
        return None
