"""An image in a request body: PNG or JPEG, grey or colour. Its size is read from its header
before a pixel is decoded (a small file can declare a gigapixel image)."""

from __future__ import annotations

import cv2
import numpy as np
from fastapi import HTTPException

from service.api.limits import PNG_SIGNATURE, png_size

JPEG_SOI = b"\xff\xd8"
JPEG_SOS = b"\xff\xda"
MAX_JPEG_SCANS = 64
"""A progressive JPEG is sent in about ten scans (libjpeg's default script: 10 in colour, 6 in
grey), a baseline one in one. Each scan costs a pass over the whole image when decoded: a
2 MB file of 12-byte scans took 49 s to decode, so more scans than this are refused before
a pixel is decoded. A 0xFF in the coded data is always followed by 0x00 or a restart
marker, so every 0xFF 0xDA is a scan's header (an embedded thumbnail's count too)."""
# Start-of-frame markers: every C0-CF but DHT (C4), JPG (C8) and DAC (CC).
_SOF = {m for m in range(0xC0, 0xD0)} - {0xC4, 0xC8, 0xCC}


def jpeg_size(data: bytes) -> tuple[int, int]:
    """(width, height) from a JPEG's start-of-frame segment, without decoding it (422 when
    its segments are damaged or hold no frame)."""
    i = 2
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            break
        marker = data[i + 1]
        if marker == 0xFF:  # fill byte
            i += 1
            continue
        if marker == 0x01 or 0xD0 <= marker <= 0xD7:  # no length
            i += 2
            continue
        length = int.from_bytes(data[i + 2:i + 4], "big")
        if marker in _SOF:
            if i + 9 > len(data):
                break
            height = int.from_bytes(data[i + 5:i + 7], "big")
            width = int.from_bytes(data[i + 7:i + 9], "big")
            if width == 0 or height == 0:
                raise HTTPException(422, f"the JPEG declares an empty image ({width}x{height})")
            return width, height
        if marker == 0xDA or length < 2:  # the scan, before any frame: damaged
            break
        i += 2 + length
    raise HTTPException(422, "the JPEG's segments are damaged: no frame header found")


def image_size(data: bytes) -> tuple[int, int]:
    """(width, height) of a PNG or JPEG body from its header (415 for anything else)."""
    if data[:8] == PNG_SIGNATURE:
        return png_size(data)
    if data[:2] == JPEG_SOI:
        size = jpeg_size(data)
        scans = data.count(JPEG_SOS)
        if scans > MAX_JPEG_SCANS:
            raise HTTPException(422, f"the JPEG is sent in {scans} scans, more than "
                                f"{MAX_JPEG_SCANS} (a progressive JPEG has about ten): save it "
                                "again as a baseline or an ordinary progressive JPEG")
        return size
    raise HTTPException(415, "the body is neither a PNG nor a JPEG image; send the image as "
                        "PNG or JPEG")


def decode_image(data: bytes) -> np.ndarray | None:
    """An image's pixels as they are, grey (H, W) or colour (H, W, 3) in OpenCV's BGR order
    (an alpha channel dropped); None when damaged. Call it off the event loop."""
    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is not None and image.ndim == 3:
        image = image[..., :3] if image.shape[2] >= 3 else image[..., 0]
    return None if image is None else np.ascontiguousarray(image)
