"""``GET /api/v1/tls/ca.pem``: the local CA certificate, so a phone can trust this console once.

Public on purpose: a CA certificate is not a secret (its key never leaves the data directory),
and the phone needs it before it can open the page over HTTPS without a warning.
"""

from __future__ import annotations

from fastapi import APIRouter, HTTPException
from fastapi.responses import Response

from server.api.deps import RuntimeDep
from server.api.models import BINARY

router = APIRouter(tags=["system"])


@router.get(
    "/tls/ca.pem",
    response_class=Response,
    responses={200: {"content": {"application/x-x509-ca-cert": BINARY}}},
)
def ca_certificate(runtime: RuntimeDep) -> Response:
    """The CA that signed this server's certificate (404 when not serving with the local CA)."""
    tls = getattr(runtime, "tls", None)
    if tls is None or tls.ca is None or not tls.ca.is_file():
        raise HTTPException(404, "this server does not use a local CA (plain HTTP or --cert)")
    return Response(
        tls.ca.read_bytes(),
        media_type="application/x-x509-ca-cert",
        headers={"Content-Disposition": 'attachment; filename="uav-console-ca.pem"'},
    )
