"""QR codes for phone pairing links, drawn server-side so the page needs no QR library."""

from __future__ import annotations

import io

import segno
from fastapi import APIRouter, Query
from fastapi.responses import Response

router = APIRouter()


@router.get("/qr.svg", include_in_schema=False)
def qr_svg(text: str = Query(..., min_length=1, max_length=512)) -> Response:
    """An SVG QR code of `text` (the phone link the teleop page shows)."""
    buffer = io.BytesIO()
    segno.make(text, error="m").save(buffer, kind="svg", scale=6, border=2)
    return Response(
        buffer.getvalue(), media_type="image/svg+xml", headers={"Cache-Control": "no-store"}
    )
