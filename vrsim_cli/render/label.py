"""The time overlay of rendered frames, drawn with Pillow.

Layer 4 (stage 3, render). OSMesa has no fonts; Pillow ships one (`ImageFont.load_default`,
a scalable font when Pillow has FreeType, a small bitmap font otherwise), so any text can
be drawn. The text sits on a translucent white box, so it reads on any background.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

TEXT_COLOR = (25, 25, 30, 255)
BOX_COLOR = (255, 255, 255, round(0.7 * 255))
FONT_PX = 12  # text height at scale 1 (frames up to 480 px tall)


@lru_cache(maxsize=8)
def _font(scale: int):
    from PIL import ImageFont, features

    if features.check("freetype2"):
        return ImageFont.load_default(size=FONT_PX * scale)
    return ImageFont.load_default()


def label_box(text: str, x: int, y: int, scale: int) -> tuple[int, int, int, int]:
    """(left, top, right, bottom) px of the box `draw_label` paints, right/bottom exclusive."""
    from PIL import Image, ImageDraw

    left, top, right, bottom = ImageDraw.Draw(Image.new("L", (1, 1))).textbbox(
        (x, y), text, font=_font(scale))
    pad = 2 * scale
    return left - pad, top - pad, right + pad, bottom + pad


def draw_label(image: np.ndarray, text: str, x: int, y: int, scale: int) -> np.ndarray:
    """`image` (h, w, 3) uint8 with `text` drawn at pixel (x, y) (its top-left corner) on
    a translucent box; what falls outside the image is clipped."""
    from PIL import Image, ImageDraw

    base = Image.fromarray(np.ascontiguousarray(image), "RGB").convert("RGBA")
    layer = Image.new("RGBA", base.size, (0, 0, 0, 0))
    draw = ImageDraw.Draw(layer)
    left, top, right, bottom = label_box(text, x, y, scale)
    draw.rectangle((left, top, right - 1, bottom - 1), fill=BOX_COLOR)
    draw.text((x, y), text, font=_font(scale), fill=TEXT_COLOR)
    return np.asarray(Image.alpha_composite(base, layer).convert("RGB"))
