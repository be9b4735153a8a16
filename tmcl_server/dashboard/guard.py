"""Who may use the dashboard: the checks every HTTP request and WebSocket upgrade passes
before aiohttp routes it (docs/dashboard.md, "Security").  No web server here: the checks
take the request's method, headers and query as plain values, so tests drive them directly.

A page the user visits elsewhere must not drive the module through the dashboard: a browser
lets any page open a WebSocket to any address (the same-origin policy does not cover
WebSockets) and tells the server where the page came from in ``Origin``.  So:

* **Origin**: a request that carries one (browsers always send it with a WebSocket, and with
  every cross-site request) must name the page's own origin (the scheme, host and port the
  request was sent to), or one the user allowed (``--http-allow-origin``).  ``Origin: null``
  (a sandboxed frame, a ``file:`` page, a redirect) names no origin and is refused.  A
  request without one (curl, a script) passes: no web page can send that.
* **Host** (DNS rebinding): a page whose name the attacker points at 127.0.0.1 after it
  loaded is "same-origin" with the dashboard; only its ``Host`` header gives it away.  On a
  loopback address the Host must be ``localhost`` (or a ``*.localhost`` name), an IP
  address, or the host of an allowed origin.
* **Token** (Jupyter's practice): listening beyond loopback, every request must carry the
  token printed at start (``?token=``, a cookie the first such request sets, or an
  ``Authorization: token ...`` header).  There the Host is not checked (users reach the
  machine by whatever name their network gives it); the token is what a rebinding page
  lacks.
"""

from __future__ import annotations

import hmac
import ipaddress
import secrets
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from urllib.parse import urlsplit

#: The environment variable that fixes the token (else a new one is drawn at every start).
TOKEN_ENV = "TMCL_HTTP_TOKEN"
#: ``--http-allow-origin *``: any origin (``null`` included).
ANY_ORIGIN = "*"
_DEFAULT_PORTS = {"http": 80, "https": 443, "ws": 80, "wss": 443}


def is_loopback(host: str) -> bool:
    """Whether a listening address reaches this machine only (``localhost`` counts)."""
    name = host.strip("[]").lower().rstrip(".")
    if name == "localhost" or name.endswith(".localhost"):
        return True
    try:
        return ipaddress.ip_address(name).is_loopback
    except ValueError:
        return False  # a host name: whatever it resolves to, treat it as the network


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def split_host(text: str, default_port: int = 80) -> tuple[str, int] | None:
    """``HOST[:PORT]`` (IPv6 in brackets) -> (lower-case host without a trailing dot, port);
    None if it does not parse."""
    text = text.strip()
    if not text:
        return None
    if text.startswith("["):
        end = text.find("]")
        if end < 0:
            return None
        host, rest = text[1:end], text[end + 1:]
        if rest and not rest.startswith(":"):
            return None
        port_text = rest[1:]
    else:
        host, sep, port_text = text.rpartition(":")
        if not sep:
            host, port_text = text, ""
    if not host:
        return None
    if port_text:
        if not port_text.isdigit() or len(port_text) > 5:
            return None
        port = int(port_text)
    else:
        port = default_port
    return host.lower().rstrip("."), port


def normalise_origin(text: str) -> str | None:
    """``scheme://host:port`` with the default port written out, or None if it is no
    origin (``null``, a path, an unknown scheme)."""
    try:
        parts = urlsplit(text.strip())
        port = parts.port
    except ValueError:
        return None
    scheme = parts.scheme.lower()
    if scheme not in _DEFAULT_PORTS or not parts.hostname or parts.path not in ("", "/"):
        return None
    host = parts.hostname.lower().rstrip(".")
    shown = f"[{host}]" if ":" in host else host
    return f"{scheme}://{shown}:{port or _DEFAULT_PORTS[scheme]}"


def new_token() -> str:
    return secrets.token_urlsafe(24)


@dataclass
class AccessPolicy:
    """The dashboard's access rules for one listening address."""

    #: The address it listens on (``127.0.0.1``, ``0.0.0.0``, ``::``, a name).
    listen_host: str
    #: Origins besides the page's own that may drive it (``--http-allow-origin``), or ``*``.
    allowed_origins: Iterable[str] = ()
    #: Required of every request (None: none); set for addresses beyond loopback.
    token: str | None = None
    #: The port it listens on (names the token's cookie: cookies do not tell ports apart).
    port: int = 0
    _origins: set[str] = field(init=False, default_factory=set)
    _hosts: set[str] = field(init=False, default_factory=set)
    _any: bool = field(init=False, default=False)
    _null: bool = field(init=False, default=False)

    def __post_init__(self) -> None:
        for origin in self.allowed_origins:
            if origin.strip() == ANY_ORIGIN:
                self._any = True
            elif origin.strip().lower() == "null":
                self._null = True
            else:
                normal = normalise_origin(origin)
                if normal is None:
                    raise ValueError(f"not an origin (scheme://host[:port]): {origin!r}")
                self._origins.add(normal)
                self._hosts.add(urlsplit(normal).hostname or "")

    @classmethod
    def for_address(cls, listen_host: str, allowed_origins: Iterable[str] = (),
                    token: str | None = None) -> AccessPolicy:
        """Loopback: no token; beyond it the given token, else a new one."""
        if is_loopback(listen_host):
            return cls(listen_host, allowed_origins, None)
        return cls(listen_host, allowed_origins, token or new_token())

    @property
    def cookie_name(self) -> str:
        return f"tmcl-dashboard-token-{self.port}"

    # -- the checks ---------------------------------------------------------------------------

    def refusal(self, headers: Mapping[str, str], query: Mapping[str, str],
                cookies: Mapping[str, str], scheme: str = "http") -> str | None:
        """Why this request is refused (one line), or None if it may go on."""
        host_header = headers.get("Host", "")
        own = split_host(host_header, _DEFAULT_PORTS.get(scheme, 80))
        if own is None:
            return "the request names no valid Host"
        if self.token is None and not self._local_host(own[0]):
            return (f"Host {host_header!r} is not this dashboard's address (a page whose name "
                    "was pointed at this machine: DNS rebinding); use http://127.0.0.1 or "
                    "http://localhost, or allow the origin with --http-allow-origin")
        origin = headers.get("Origin")
        if origin is not None and not self._origin_allowed(origin, own, scheme):
            return (f"Origin {origin!r} is not this page's own: another web page may not drive "
                    "the dashboard (--http-allow-origin ORIGIN allows one)")
        if self.token is not None and not self.authorised(headers, query, cookies):
            return ("this dashboard listens beyond loopback and needs its token: open the URL "
                    "tmcl-server printed (…/?token=…)")
        return None

    def _local_host(self, host: str) -> bool:
        return (host == "localhost" or host.endswith(".localhost") or _is_ip(host.strip("[]"))
                or host in self._hosts or self._any)

    def _origin_allowed(self, origin: str, own: tuple[str, int], scheme: str) -> bool:
        if self._any:
            return True
        if origin.strip().lower() == "null":
            return self._null
        normal = normalise_origin(origin)
        if normal is None:
            return False
        if normal in self._origins:
            return True
        parts = urlsplit(normal)
        return parts.scheme == scheme and ((parts.hostname or ""), parts.port) == own

    def presented_token(self, headers: Mapping[str, str], query: Mapping[str, str],
                        cookies: Mapping[str, str]) -> str | None:
        """The token a request carries: ``?token=``, ``Authorization: token|Bearer``, the cookie."""
        if "token" in query:
            return query["token"]
        authorization = headers.get("Authorization", "")
        kind, _, value = authorization.strip().partition(" ")
        if kind.lower() in ("token", "bearer") and value:
            return value.strip()
        return cookies.get(self.cookie_name)

    def authorised(self, headers: Mapping[str, str], query: Mapping[str, str],
                   cookies: Mapping[str, str]) -> bool:
        if self.token is None:
            return True
        given = self.presented_token(headers, query, cookies)
        if given is None:
            return False
        try:  # as bytes: a header or cookie that is not UTF-8 is a wrong token, not a 500 (N7)
            presented = given.encode("utf-8", "surrogateescape")
        except UnicodeError:
            return False
        return hmac.compare_digest(presented, self.token.encode())
