"""A small raster plotter for the tile quicklooks: views of an image in data axes, their
ticks and labels, colour bars, texts and contact markers, drawn straight into pixels
(numpy for the images, PIL for text and shapes) and saved as a palette PNG.

Why not matplotlib: a 3 m tile's products quicklook (six views, some 150 texts) took
0.9-1.7 CPU s with matplotlib on a 2-core Zen 3, nearly all of it in creating and
drawing artists; the worker writes one a tile, every ``svss process`` and ``svss
batch`` too (issue 32, docs/products.md). Here the same figure costs 0.10-0.12 s, and
importing the quicklooks no longer imports pyplot.

Conventions: pixel coordinates with the origin at the image's top-left, x to the right
and y down; sizes of texts and lines are in points (1/72 inch) at the canvas's dpi; a
:class:`View` maps data coordinates to pixels (x to the right; y up, or down for
depth)."""

from __future__ import annotations

import functools
import importlib.util
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

#: the fonts (matplotlib's own DejaVu, so the quicklooks look as its figures do)
FONT_FILES = {"sans": "DejaVuSans.ttf", "bold": "DejaVuSans-Bold.ttf",
              "mono": "DejaVuSansMono.ttf"}
#: tick marks outside the axes, points, and the gap from a tick to its label
TICK_PT, TICK_PAD_PT = 3.5, 2.0
#: the least space between tick labels along an axis, in label heights (y axes) and
#: label widths of a typical "-10.5" (x axes)
Y_TICK_SPACING, X_TICK_SPACING = 2.5, 2.6
#: the mantissas of tick steps, in order of preference
NICE_STEPS = (1.0, 2.0, 2.5, 5.0, 10.0)
MINUS = "\u2212"


def _font_dir() -> Path:
    spec = importlib.util.find_spec("matplotlib")
    if spec is None or not spec.submodule_search_locations:
        raise RuntimeError("the quicklooks use matplotlib's DejaVu fonts: matplotlib is "
                           "not installed")
    return Path(spec.submodule_search_locations[0]) / "mpl-data" / "fonts" / "ttf"


@functools.lru_cache(maxsize=32)
def font(kind: str, size_px: float) -> ImageFont.FreeTypeFont:
    """The ``kind`` font (:data:`FONT_FILES`) at ``size_px`` pixels (cached)."""
    return ImageFont.truetype(str(_font_dir() / FONT_FILES[kind]), size=size_px)


def nice_ticks(lo: float, hi: float, max_ticks: int) -> tuple[np.ndarray, int]:
    """Tick values in ``[lo, hi]`` on the roundest step (1, 2, 2.5 or 5 times a power
    of ten) that gives at most ``max_ticks`` of them (at least 2 where the span allows),
    and the decimals their labels need."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return np.array([lo]) if math.isfinite(lo) else np.array([]), 0
    max_ticks = max(int(max_ticks), 2)
    raw = (hi - lo) / (max_ticks - 1)
    exp = math.floor(math.log10(raw))
    for m in NICE_STEPS:
        step = m * 10.0 ** exp
        first = math.ceil(lo / step - 1e-9)
        last = math.floor(hi / step + 1e-9)
        if last - first + 1 <= max_ticks:
            break
    values = np.arange(first, last + 1) * step
    decimals = max(0, -exp + (1 if m == 2.5 else 0)) if m < 10 else max(0, -exp - 1)
    return values, decimals


def tick_label(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}"
    if float(text) == 0.0:
        text = text.lstrip("-")
    return text.replace("-", MINUS)


def rgb8(colour) -> tuple[int, int, int]:
    """A colour given as floats in [0, 1] (RGB or RGBA) as 8-bit RGB."""
    return tuple(int(round(255 * float(v))) for v in colour[:3])


@dataclass(frozen=True)
class View:
    """An axes box in pixels (``x0``, ``y0`` its top-left corner, ``w`` x ``h``) showing
    data ``x`` in ``xe`` (left to right) and ``y`` in ``ye`` (bottom to top, or top to
    bottom where ``y_down``: depth)."""

    x0: int
    y0: int
    w: int
    h: int
    xe: tuple[float, float]
    ye: tuple[float, float]
    y_down: bool

    def to_px(self, x, y) -> np.ndarray:
        """Pixel positions (n, 2) of data points ``x``, ``y``."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        fx = (x - self.xe[0]) / (self.xe[1] - self.xe[0])
        fy = (y - self.ye[0]) / (self.ye[1] - self.ye[0])
        if not self.y_down:
            fy = 1.0 - fy
        return np.column_stack([self.x0 + fx * self.w, self.y0 + fy * self.h])

    def at(self, fx: float, fy: float) -> tuple[float, float]:
        """The pixel at axes fractions ``fx`` (from the left), ``fy`` (from the
        bottom)."""
        return self.x0 + fx * self.w, self.y0 + (1.0 - fy) * self.h


class Canvas:
    """A white RGB image of ``width_in`` x ``height_in`` inches at ``dpi``."""

    def __init__(self, width_in: float, height_in: float, dpi: int):
        self.dpi = dpi
        self.width = max(1, int(round(width_in * dpi)))
        self.height = max(1, int(round(height_in * dpi)))
        self.image = Image.new("RGB", (self.width, self.height), (255, 255, 255))
        self.draw = ImageDraw.Draw(self.image)

    def px(self, points: float) -> float:
        return points * self.dpi / 72.0

    def box(self, left_in: float, top_in: float, w_in: float, h_in: float):
        """A box in whole pixels from one in inches (from the top-left corner)."""
        x0, y0 = int(round(left_in * self.dpi)), int(round(top_in * self.dpi))
        return (x0, y0, max(1, int(round((left_in + w_in) * self.dpi)) - x0),
                max(1, int(round((top_in + h_in) * self.dpi)) - y0))

    # ------------------------------------------------------------------- texts
    def text(self, xy, text: str, size_pt: float, anchor: str = "la", kind: str = "sans",
             fill=(0, 0, 0), align: str = "left") -> tuple[int, int, int, int]:
        """Draw ``text`` (lines allowed) with its ``anchor`` point at ``xy``: two letters
        as PIL's, horizontal l/m/r and vertical a (top), m (middle), d (bottom), s
        (the first line's baseline); returns its bounding box."""
        f = font(kind, self.px(size_pt))
        x0, y0, x1, y1 = self.draw.multiline_textbbox((0, 0), text, font=f, anchor="la",
                                                      align=align)
        w, h = x1 - x0, y1 - y0
        hx, vy = anchor[0], anchor[1]
        x = xy[0] - {"l": 0.0, "m": w / 2, "r": w}[hx] - x0
        if vy == "s":
            y = xy[1] - f.getmetrics()[0]
        else:
            y = xy[1] - {"a": 0.0, "m": h / 2, "d": h}[vy] - y0
        self.draw.multiline_text((x, y), text, font=f, fill=fill, anchor="la", align=align)
        return int(x + x0), int(y + y0), int(x + x1), int(y + y1)

    def text_size(self, text: str, size_pt: float, kind: str = "sans") -> tuple[int, int]:
        b = self.draw.multiline_textbbox((0, 0), text, font=font(kind, self.px(size_pt)))
        return math.ceil(b[2] - b[0]), math.ceil(b[3] - b[1])

    def text_up(self, xy, text: str, size_pt: float, fill=(0, 0, 0)) -> None:
        """``text`` turned a quarter left (read bottom to top), centred at ``xy``."""
        f = font("sans", self.px(size_pt))
        b = self.draw.multiline_textbbox((0, 0), text, font=f, align="center")
        mask = Image.new("L", (math.ceil(b[2] - b[0]) + 2, math.ceil(b[3] - b[1]) + 2), 0)
        ImageDraw.Draw(mask).multiline_text((1 - b[0], 1 - b[1]), text, font=f, fill=255,
                                            align="center")
        mask = mask.transpose(Image.Transpose.ROTATE_90)
        self.image.paste(fill, (int(round(xy[0] - mask.width / 2)),
                                int(round(xy[1] - mask.height / 2))), mask)

    def label_box(self, xy, text: str, size_pt: float, anchor: str, fill=(255, 255, 255),
                  back=(38, 38, 38), alpha: float = 0.7) -> None:
        """Bold ``text`` on a box of ``back`` blended at ``alpha`` over the picture."""
        w, h = self.text_size(text, size_pt, "bold")
        pad = int(round(self.px(0.15 * size_pt)))
        x = xy[0] - {"l": 0.0, "m": w / 2, "r": w}[anchor[0]]
        y = xy[1] - {"a": 0.0, "m": h / 2, "d": h}[anchor[1]]
        x0, y0 = max(0, int(x) - pad), max(0, int(y) - pad)
        x1 = min(self.width, int(x + w) + pad + 1)
        y1 = min(self.height, int(y + h) + pad + 1)
        if x1 > x0 and y1 > y0:
            region = np.asarray(self.image.crop((x0, y0, x1, y1)), dtype=np.float32)
            region = (1 - alpha) * region + alpha * np.asarray(back, dtype=np.float32)
            self.image.paste(Image.fromarray(region.round().astype(np.uint8)), (x0, y0))
        self.text((x, y), text, size_pt, "la", "bold", fill)

    # ------------------------------------------------------------------ images
    def view(self, box, rgba: np.ndarray, xe, ye, y_down: bool) -> View:
        """Draw ``rgba`` (x index first: (nx, ny, 3 or 4), floats in [0, 1]) into
        ``box`` (pixels) by nearest neighbour, framed; ``xe``, ``ye``: the data extents
        of its outer voxel edges."""
        x0, y0, w, h = box
        v = View(x0, y0, w, h, (float(xe[0]), float(xe[1])), (float(ye[0]), float(ye[1])),
                 y_down)
        nx, ny = rgba.shape[:2]
        cols = np.minimum(((np.arange(w) + 0.5) * nx / w).astype(np.int64), nx - 1)
        rows = np.minimum(((np.arange(h) + 0.5) * ny / h).astype(np.int64), ny - 1)
        if not y_down:
            rows = rows[::-1]
        lut = np.clip(np.round(np.asarray(rgba)[..., :3] * 255.0), 0, 255).astype(np.uint8)
        self.image.paste(Image.fromarray(np.ascontiguousarray(
            lut[cols][:, rows].transpose(1, 0, 2))), (x0, y0))
        self.frame(v)
        return v

    def frame(self, v: View) -> None:
        self.draw.rectangle((v.x0 - 1, v.y0 - 1, v.x0 + v.w, v.y0 + v.h), outline=(0, 0, 0))

    # ------------------------------------------------------------------- axes
    def x_axis(self, v: View, label: str, size_pt: float = 7, label_pt: float = 8,
               max_ticks: int | None = None) -> None:
        """Ticks and their labels under ``v``, and the axis label below them."""
        label_w = self.text_size(f"{MINUS}10.5", size_pt)[0]
        n = max_ticks or max(2, int(v.w / (X_TICK_SPACING * label_w)) + 1)
        values, dec = nice_ticks(v.xe[0], v.xe[1], n)
        tick, pad = self.px(TICK_PT), self.px(TICK_PAD_PT)
        y = v.y0 + v.h
        bottom = y + tick + pad
        for t in values:
            x = v.to_px([t], [v.ye[0]])[0, 0]
            self.draw.line((x, y, x, y + tick), fill=(0, 0, 0))
            b = self.text((x, y + tick + pad), tick_label(t, dec), size_pt, "ma")
            bottom = max(bottom, b[3])
        self.text((v.x0 + v.w / 2, bottom + pad), label, label_pt, "ma")

    def y_axis(self, v: View, label: str, size_pt: float = 7, label_pt: float = 8) -> None:
        """Ticks and their labels left of ``v``, and the axis label, turned, left of
        them."""
        label_h = self.text_size("0", size_pt)[1]
        n = max(2, int(v.h / (Y_TICK_SPACING * label_h)) + 1)
        values, dec = nice_ticks(v.ye[0], v.ye[1], n)
        tick, pad = self.px(TICK_PT), self.px(TICK_PAD_PT)
        x = v.x0 - 1
        left = x - tick - pad
        for t in values:
            y = v.to_px([v.xe[0]], [t])[0, 1]
            self.draw.line((x - tick, y, x, y), fill=(0, 0, 0))
            b = self.text((x - tick - pad, y), tick_label(t, dec), size_pt, "rm")
            left = min(left, b[0])
        h = self.text_size(label, label_pt)[1]
        self.text_up((left - pad - h / 2, v.y0 + v.h / 2), label, label_pt)

    def title(self, v: View, text: str, size_pt: float = 9) -> None:
        self.text((v.x0, v.y0 - self.px(3)), text, size_pt, "ld")

    def colour_bar(self, box, lut: np.ndarray, ticks_u, labels, label: str,
                   size_pt: float = 7, label_pt: float = 8) -> None:
        """A vertical bar of the colours ``lut`` ((n, 3 or 4) floats, bottom to top) in
        ``box``, ticks at the fractions ``ticks_u`` labelled ``labels`` on its right, and
        ``label`` (turned) beyond them."""
        x0, y0, w, h = box
        rgba = np.repeat(np.asarray(lut)[None, :, :], 2, axis=0)
        v = self.view(box, rgba, (0.0, 1.0), (0.0, 1.0), y_down=False)
        tick, pad = self.px(TICK_PT), self.px(TICK_PAD_PT)
        right = x0 + w + tick + pad
        for u, text in zip(ticks_u, labels):
            y = v.to_px([0.0], [float(u)])[0, 1]
            self.draw.line((x0 + w, y, x0 + w + tick, y), fill=(0, 0, 0))
            right = max(right, self.text((x0 + w + tick + pad, y), text, size_pt, "lm")[2])
        lh = self.text_size(label, label_pt)[1]
        self.text_up((right + pad + lh / 2, y0 + h / 2), label, label_pt)

    # ----------------------------------------------------------------- markers
    def circles(self, xy_px: np.ndarray, diameter_pt: float, colour, width_pt: float,
                clip: View) -> None:
        """Unfilled circles centred at ``xy_px`` (n, 2), inside ``clip`` only."""
        r = self.px(diameter_pt) / 2
        lw = max(1, int(round(self.px(width_pt))))
        fill = rgb8(colour)
        for x, y in np.asarray(xy_px, dtype=np.float64).reshape(-1, 2):
            if clip.x0 <= x <= clip.x0 + clip.w and clip.y0 <= y <= clip.y0 + clip.h:
                self.draw.ellipse((x - r, y - r, x + r, y + r), outline=fill, width=lw)

    # ------------------------------------------------------------------- output
    def pixels(self) -> np.ndarray:
        return np.asarray(self.image)

    def save_palette_png(self, path: Path, palette: tuple[int, ...],
                         compress_level: int) -> None:
        save_rgb_palette_png(self.image, path, palette, compress_level)


def save_rgb_palette_png(image: Image.Image, path: Path, palette: tuple[int, ...],
                         compress_level: int) -> None:
    """``image`` (RGB) mapped to the nearest colours of ``palette`` (768 values, no
    dithering) and written as a palette PNG at zlib level ``compress_level``."""
    pal = Image.new("P", (1, 1))
    pal.putpalette(list(palette))
    image.quantize(palette=pal, dither=Image.Dither.NONE).save(
        path, format="PNG", compress_level=compress_level)
