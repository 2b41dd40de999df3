"""Where a console request comes from: the socket's peer, and the address a trusted proxy says
it forwarded for.

Why the console reads ``X-Forwarded-For`` itself (uvicorn runs with ``proxy_headers`` off,
``SERVER_OPTIONS`` in ``app.py``): uvicorn trusts the header from 127.0.0.1 by default and then
*replaces* the peer with it, so any local process chose its own address, escaped its throttle
and wrote a forged address into the audit (issue 48). Here the header counts only when the
socket's peer is one of the proxies named with ``--trusted-proxy`` (none by default), and the
audit keeps both: ``client`` is always the peer, ``forwarded_for`` the proxy's word.

The throttle's key of an address (``source_key``): loopback is one source (a local process can
bind any of 127.0.0.0/8, so counting them apart would give it 16 million fresh sources), an
IPv6 address counts by its /64 (one host's share), any other IPv4 address by itself.
"""

from __future__ import annotations

import ipaddress
from collections.abc import Iterable
from dataclasses import dataclass

from monitor.errors import ConfigError

FORWARDED_HEADER = "x-forwarded-for"
MAX_HOPS = 16  # entries of X-Forwarded-For read from its end; more are a forgery or a loop
MAX_ADDRESS_CHARS = 64

Network = ipaddress.IPv4Network | ipaddress.IPv6Network


def _address(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    text = text.strip()
    if text.startswith("[") and "]" in text:  # [v6]:port
        text = text[1:text.index("]")]
    try:
        ip = ipaddress.ip_address(text)
    except ValueError:
        return None
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        return ip.ipv4_mapped
    return ip


def source_key(address: str) -> str:
    """The throttle's key of ``address`` (see the module's docstring)."""
    ip = _address(address)
    if ip is None:
        return address[:MAX_ADDRESS_CHARS]  # not an address (a test client's name): as it is
    if ip.is_loopback:
        return "loopback"
    if isinstance(ip, ipaddress.IPv6Address):
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)


@dataclass(frozen=True)
class Source:
    """A request's origin: ``peer`` the socket's, ``forwarded`` what a trusted proxy said."""

    peer: str
    forwarded: str | None = None

    @property
    def address(self) -> str:
        """Who is counted: the forwarded address behind a trusted proxy, else the peer."""
        return self.forwarded or self.peer

    @property
    def key(self) -> str:
        return source_key(self.address)

    def fields(self) -> dict[str, str]:
        """The audit's fields: ``client`` (the peer, always), ``forwarded_for`` (if any)."""
        out = {"client": self.peer}
        if self.forwarded:
            out["forwarded_for"] = self.forwarded
        return out

    def __str__(self) -> str:
        return f"{self.forwarded} (via proxy {self.peer})" if self.forwarded else self.peer


class TrustedProxies:
    """The proxies whose ``X-Forwarded-For`` the console believes (addresses or networks)."""

    def __init__(self, items: Iterable[str] = ()) -> None:
        networks: list[Network] = []
        for item in items:
            try:
                networks.append(ipaddress.ip_network(item.strip(), strict=False))
            except ValueError:
                raise ConfigError(f"--trusted-proxy {item!r}: not an IP address or network "
                                  "(e.g. 10.0.0.2 or 10.0.0.0/24)") from None
        self.networks = tuple(networks)

    def __bool__(self) -> bool:
        return bool(self.networks)

    def trusts(self, address: str) -> bool:
        ip = _address(address)
        return ip is not None and any(ip.version == n.version and ip in n
                                      for n in self.networks)

    def source(self, peer: str, forwarded_headers: list[str]) -> Source:
        """The source of a request from ``peer`` carrying these ``X-Forwarded-For`` values:
        the header is read only from a trusted peer, from its end (the entry the trusted proxy
        appended), skipping further trusted proxies; the first other entry is the client. An
        entry that is not an address ends the walk (nothing before it is believed)."""
        if not self.networks or not forwarded_headers or not self.trusts(peer):
            return Source(peer)
        hops = [h.strip() for h in ",".join(forwarded_headers).split(",")][-MAX_HOPS:]
        for hop in reversed(hops):
            ip = _address(hop)
            if ip is None:
                break
            if not self.trusts(str(ip)):
                return Source(peer, str(ip))
        return Source(peer)


def request_source(request, proxies: TrustedProxies) -> Source:
    """The ``Source`` of a Starlette request."""
    peer = request.client.host if request.client else ""
    return proxies.source(peer, request.headers.getlist(FORWARDED_HEADER))
