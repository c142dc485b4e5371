"""Why a ``tls/`` router is not trusted: Zenoh's own refusal says only "Unable to connect", the
same words as for a router that is not up, so a client that could not join looks at the router's
certificate itself (one TLS handshake, nothing sent after it) and says what is wrong with it."""

from __future__ import annotations

import socket
import ssl

PROBE_TIMEOUT_S = 3.0  # a router that answers does so within milliseconds on any live link


def split_endpoint(endpoint: str) -> tuple[str, str, int] | None:
    """``(protocol, host, port)`` of ``tcp/HOST:PORT``-style endpoints (``[v6]`` unwrapped);
    None when it has no port."""
    proto, _, rest = endpoint.partition("/")
    host, _, port = rest.rpartition(":")
    if not port.isdigit() or not host:
        return None
    return proto, host.strip("[]"), int(port)


def untrusted(endpoint: str, ca: str, timeout_s: float = PROBE_TIMEOUT_S) -> str | None:
    """Why the router at ``endpoint`` (``tls/HOST:PORT``) is not trusted by the CA file ``ca``,
    as its certificate is checked (the CA's signature, its name for ``HOST``); None when it is
    trusted, when ``endpoint`` is not ``tls/``, or when nothing answers there (not up: nothing to
    judge yet)."""
    parts = split_endpoint(endpoint)
    if parts is None or parts[0] != "tls":
        return None
    _, host, port = parts
    try:
        context = ssl.create_default_context(cafile=ca)
    except (OSError, ssl.SSLError) as exc:
        return f"cannot be checked: the CA file {ca} does not load ({exc})"
    try:
        sock = socket.create_connection((host, port), timeout=timeout_s)
    except OSError:
        return None
    try:
        with context.wrap_socket(sock, server_hostname=host):
            return None
    except ssl.SSLCertVerificationError as exc:
        return f"presents a certificate that {ca} does not trust ({exc.verify_message})"
    except ssl.SSLError as exc:
        return f"does not speak TLS as a bus router does ({exc})"
    except OSError:  # the connection went before the handshake ended: nothing to judge
        return None
    finally:
        sock.close()
