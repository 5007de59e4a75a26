"""TLS for ``wss://`` URLs."""

from __future__ import annotations

import ssl


def context(url: str, cafile: str | None) -> ssl.SSLContext | None:
    """The TLS context for ``url``: the system's trust store, or only
    ``cafile`` (a PEM file of CA certificates, e.g. a self-signed one)."""
    secure = url.lower().startswith("wss://")
    if cafile is None:
        return ssl.create_default_context() if secure else None
    if not secure:
        raise ValueError(f"cafile is for wss:// URLs, not {url!r}")
    return ssl.create_default_context(cafile=cafile)
