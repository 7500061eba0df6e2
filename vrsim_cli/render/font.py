"""A 5x7 bitmap font for the time overlay, drawn into the image with numpy.

OSMesa has no fonts and this needs none: the glyphs are the characters the overlay uses
(`t = 12.345 s`), each 7 rows of 5 pixels, scaled by whole pixels.
"""

from __future__ import annotations

import numpy as np

GLYPH_W, GLYPH_H = 5, 7

_GLYPHS = {
    "0": ["01110", "10001", "10011", "10101", "11001", "10001", "01110"],
    "1": ["00100", "01100", "00100", "00100", "00100", "00100", "01110"],
    "2": ["01110", "10001", "00001", "00010", "00100", "01000", "11111"],
    "3": ["11110", "00001", "00001", "01110", "00001", "00001", "11110"],
    "4": ["00010", "00110", "01010", "10010", "11111", "00010", "00010"],
    "5": ["11111", "10000", "11110", "00001", "00001", "10001", "01110"],
    "6": ["00110", "01000", "10000", "11110", "10001", "10001", "01110"],
    "7": ["11111", "00001", "00010", "00100", "01000", "01000", "01000"],
    "8": ["01110", "10001", "10001", "01110", "10001", "10001", "01110"],
    "9": ["01110", "10001", "10001", "01111", "00001", "00010", "01100"],
    ".": ["00000", "00000", "00000", "00000", "00000", "01100", "01100"],
    "-": ["00000", "00000", "00000", "11111", "00000", "00000", "00000"],
    "=": ["00000", "00000", "11111", "00000", "11111", "00000", "00000"],
    "t": ["01000", "01000", "11100", "01000", "01000", "01001", "00110"],
    "s": ["00000", "00000", "01110", "10000", "01110", "00001", "11110"],
    " ": ["00000"] * 7,
}
GLYPHS = {ch: np.array([[c == "1" for c in row] for row in rows]) for ch, rows in
          _GLYPHS.items()}


def text_mask(text: str, scale: int = 1) -> np.ndarray:
    """(7 * scale, 6 * scale * len(text)) bool: the pixels of `text`, one column of space
    after each glyph. Characters without a glyph raise KeyError."""
    if not text:
        return np.zeros((GLYPH_H * scale, 0), dtype=bool)
    gap = np.zeros((GLYPH_H, 1), dtype=bool)
    row = np.hstack([np.hstack([GLYPHS[ch], gap]) for ch in text])
    return row.repeat(scale, axis=0).repeat(scale, axis=1)


def draw_text(image: np.ndarray, text: str, x: int, y: int, scale: int,
              color=(25, 25, 30), box=(255, 255, 255), box_alpha: float = 0.7) -> None:
    """Draw `text` into `image` (h, w, 3) uint8 with its top-left corner at pixel (x, y),
    on a translucent box (padding 2 * scale) so it reads on any background. Whatever
    falls outside the image is clipped."""
    mask = text_mask(text, scale)
    pad = 2 * scale
    top, left = max(0, y - pad), max(0, x - pad)
    bottom = min(image.shape[0], y + mask.shape[0] + pad)
    right = min(image.shape[1], x + mask.shape[1] + pad)
    if bottom <= top or right <= left:
        return
    region = image[top:bottom, left:right]
    region[:] = np.round((1.0 - box_alpha) * region + box_alpha * np.asarray(box))
    h = min(mask.shape[0], image.shape[0] - y)
    w = min(mask.shape[1], image.shape[1] - x)
    if h > 0 and w > 0:
        image[y:y + h, x:x + w][mask[:h, :w]] = color
