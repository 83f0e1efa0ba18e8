"""Which addresses the service may listen on: pure functions, no I/O.

Loopback is always allowed. Any other address (0.0.0.0, a LAN address, ::) needs auth on and at
least one API token made on purpose (``evcbench token create``), not only the local bootstrap one.
"""

from __future__ import annotations

import ipaddress


def is_loopback(host: str | None) -> bool:
    """True for 127.0.0.0/8, ::1 and 'localhost'; False for 0.0.0.0, '', and any other name."""
    host = (host or "").strip().strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def auth_refusal(host: str, auth: str) -> str | None:
    """Why ``auth`` may not be used on ``host`` (auth off off loopback), or None."""
    if auth != "tokens" and not is_loopback(host):
        return (
            f"refusing to listen on {host}: auth is {auth!r}, which is allowed only on loopback "
            f"(127.0.0.1); use --auth tokens"
        )
    return None


def bind_refusal(host: str, auth: str, remote_token_count: int) -> str | None:
    """Why the service must not listen on ``host``, or None if it may."""
    if is_loopback(host):
        return None
    refusal = auth_refusal(host, auth)
    if refusal:
        return refusal
    if remote_token_count == 0:
        return (
            f"refusing to listen on {host}: it is not a loopback address and no API token exists "
            f"besides the local bootstrap one; create one first with "
            f"`evcbench token create --name NAME --scope operate` (same --data-dir)"
        )
    return None
