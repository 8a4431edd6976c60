"""Loss curves as a PNG without plotting libraries: log-scaled lines per series on a grid,
drawn with numpy and written with zlib."""

from __future__ import annotations

import math
import struct
import zlib
from pathlib import Path

import numpy as np

from .checkpoint import write_file_atomic

COLOURS = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189)]


def write_png(path: str | Path, rgb: np.ndarray) -> None:
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].astype(np.uint8).tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    write_file_atomic(Path(path), png)


def curves(path: str | Path, series: dict[str, list[tuple[int, float]]], width: int = 800, height: int = 300) -> None:
    """One panel per series (x: step, y: log10 of the value), stacked vertically."""
    names = [n for n, pts in series.items() if pts]
    img = np.full((height * max(1, len(names)), width, 3), 255, np.uint8)
    for i, name in enumerate(names):
        pts = [(s, v) for s, v in series[name] if v > 0 and math.isfinite(v)]
        if len(pts) < 2:
            continue
        top = i * height
        xs = np.array([p[0] for p in pts], float)
        ys = np.log10(np.array([p[1] for p in pts], float))
        x0, x1, y0, y1 = xs.min(), max(xs.max(), xs.min() + 1), ys.min(), max(ys.max(), ys.min() + 1e-6)
        img[top + height - 1, :] = 200
        for gx in range(0, width, width // 10):
            img[top:top + height, gx] = 235
        px = ((xs - x0) / (x1 - x0) * (width - 21) + 10).astype(int)
        py = (top + height - 11 - (ys - y0) / (y1 - y0) * (height - 21)).astype(int)
        colour = COLOURS[i % len(COLOURS)]
        for a in range(len(px) - 1):
            n = max(abs(px[a + 1] - px[a]), abs(py[a + 1] - py[a]), 1)
            for t in np.linspace(0, 1, n + 1):
                x = int(round(px[a] + t * (px[a + 1] - px[a])))
                y = int(round(py[a] + t * (py[a + 1] - py[a])))
                img[max(top, y - 1):y + 1, max(0, x - 1):x + 1] = colour
    write_png(path, img)


def point_sheet(path: str | Path, frames: list, tile: int = 200) -> None:
    """Point clouds side by side, each seen from the front (x right, y up), white on
    black, scaled so the largest frame fills its tile."""
    clouds = [np.asarray(f, float) for f in frames if len(f)]
    img = np.zeros((tile, tile * max(1, len(clouds)), 3), np.uint8)
    if not clouds:
        write_png(path, img)
        return
    extent = max(max(np.ptp(c[:, 0]), np.ptp(c[:, 1])) for c in clouds) * 1.1
    for i, c in enumerate(clouds):
        centre = np.array([(c[:, 0].max() + c[:, 0].min()) / 2, (c[:, 1].max() + c[:, 1].min()) / 2])
        x = ((c[:, 0] - centre[0]) / extent + 0.5) * (tile - 1)
        y = (0.5 - (c[:, 1] - centre[1]) / extent) * (tile - 1)
        ok = (x >= 0) & (x < tile) & (y >= 0) & (y < tile)
        img[y[ok].astype(int), (x[ok] + i * tile).astype(int)] = 230
        img[:, i * tile] = 60
    write_png(path, img)
