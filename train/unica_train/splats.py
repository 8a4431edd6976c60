"""Gaussian splats in PyTorch (docs/architecture.md, Appearance), the same meaning as the Rust side:

- base splats from a frame's foreground points: each pixel's local surface frame from its
  map neighbours (src/splat/base.rs does the same arithmetic);
- a differentiable tile renderer with the rasterizer's projection (src/splat/project.rs:
  EWA, +0.3 px low-pass, 3σ radius, front-to-back blending, alpha ≤ 0.99);
- image metrics: PSNR and SSIM (11-tap Gaussian window, σ 1.5)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F

SH_C0 = 0.28209479177387814
# Base splats: σ along the surface as a share of the pixel footprint, thickness as a
# share of the smaller footprint, opacity.
SPREAD = 0.6
THICKNESS = 0.1
OPACITY = 0.95
# Above level 256 (the refiner's training level) the drawn splats are this much wider
# along the surface (src/splat/base.rs FINE_WIDEN, with its measurement).
FINE_WIDEN = 2.0
# The views of the map (row, col, rows, cols), in the order of src/posmap/table.rs.
VIEWS = [(0, 0, 96, 48), (0, 48, 96, 48), (0, 96, 96, 32), (96, 0, 32, 96), (96, 96, 16, 32), (112, 96, 16, 32)]
FOV_Y = 0.8
TILE = 16
# Tiles blended at once (bounds the renderer's memory).
TILE_CHUNK = 32


def view_of(row: torch.Tensor, col: torch.Tensor) -> torch.Tensor:
    out = torch.full_like(row, -1)
    for v, (r, c, rows, cols) in enumerate(VIEWS):
        inside = (row >= r) & (row < r + rows) & (col >= c) & (col < c + cols)
        out = torch.where(inside, torch.full_like(row, v), out)
    return out


def neighbours(pixels: torch.Tensor, size: int) -> torch.Tensor:
    """[N, 4] indices of each foreground pixel's right, left, lower and upper neighbour in
    the same view (-1 where there is none). `size` is the map's side; the views scale with
    it from the 128 layout."""
    index = torch.full((size * size,), -1, dtype=torch.long)
    index[pixels] = torch.arange(len(pixels))
    row, col = pixels // size, pixels % size
    factor = size // 128
    view = view_of(row // factor, col // factor)
    out = []
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        r, c = row + dr, col + dc
        ok = (r >= 0) & (r < size) & (c >= 0) & (c < size)
        n = torch.where(ok, index[(r.clamp(0, size - 1) * size + c.clamp(0, size - 1))], torch.full_like(row, -1))
        same = view_of(r.clamp(0, size - 1) // factor, c.clamp(0, size - 1) // factor) == view
        out.append(torch.where(same & (n >= 0), n, torch.full_like(n, -1)))
    return torch.stack(out, 1)


def _helper_perpendicular(t: torch.Tensor) -> torch.Tensor:
    """A unit vector perpendicular to t (with Y as helper unless t is near Y, then X)."""
    unit = t / t.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    near_y = unit[..., 1].abs() > 0.9
    helper = torch.where(near_y[..., None], torch.tensor([1.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]))
    p = torch.cross(helper, unit, dim=-1)
    return p / p.norm(dim=-1, keepdim=True).clamp_min(1e-30)


def median_spacing(points: torch.Tensor, nbrs: torch.Tensor) -> torch.Tensor:
    """The median distance to the right and lower neighbours (sorted[len // 2])."""
    d = []
    for k in (0, 2):
        ok = nbrs[:, k] >= 0
        d.append((points[nbrs[ok, k]] - points[ok]).norm(dim=-1))
    d = torch.cat(d).sort().values
    return d[len(d) // 2]


def tangents(points: torch.Tensor, nbrs: torch.Tensor):
    """Each point's tangents along map columns (u) and rows (v), per pixel step: central
    differences over the neighbours within 3× the median spacing (one-sided at edges);
    a missing one is replaced by a perpendicular of the same length, both missing by
    the median along X and Y. Returns (u, v, median)."""
    median = median_spacing(points, nbrs)
    limit = 3.0 * median

    def axis(forward: int, backward: int):
        total = torch.zeros_like(points)
        count = torch.zeros(points.shape[0])
        for k, sign in ((forward, 1.0), (backward, -1.0)):
            n = nbrs[:, k]
            q = points[n.clamp_min(0)]
            d = q - points
            ok = (n >= 0) & (d.norm(dim=-1) <= limit)
            total = total + torch.where(ok[:, None], sign * d, torch.zeros_like(d))
            count = count + ok.float()
        return total / count.clamp_min(1)[:, None], count > 0

    u, has_u = axis(0, 1)
    v, has_v = axis(2, 3)
    u_alt = torch.cross(_helper_perpendicular(v), v, dim=-1)
    v_alt = torch.cross(_helper_perpendicular(u), u, dim=-1)
    u_fill = torch.where(has_v[:, None], u_alt, median * torch.tensor([1.0, 0.0, 0.0]))
    v_fill = torch.where(has_u[:, None], v_alt, median * torch.tensor([0.0, 1.0, 0.0]))
    u = torch.where(has_u[:, None], u, u_fill)
    v = torch.where(has_v[:, None], v, v_fill)
    return u, v, median


def quat_from_matrix(m: torch.Tensor) -> torch.Tensor:
    """Rotation matrices [..., 3, 3] -> unit quaternions [..., 4] as (x, y, z, w), w ≥ 0
    (Shepperd's method: the largest of w, x, y, z from the diagonal, the rest from the
    off-diagonal terms; src/splat/base.rs does the same)."""
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    a, b = m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0]
    c = m[..., 1, 0] - m[..., 0, 1]
    xy, xz, yz = m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1]
    trace = m00 + m11 + m22
    s0 = (trace + 1).clamp_min(1e-12).sqrt() * 2
    s1 = (1 + m00 - m11 - m22).clamp_min(1e-12).sqrt() * 2
    s2 = (1 + m11 - m00 - m22).clamp_min(1e-12).sqrt() * 2
    s3 = (1 + m22 - m00 - m11).clamp_min(1e-12).sqrt() * 2
    q0 = torch.stack([a / s0, b / s0, c / s0, s0 / 4], -1)
    q1 = torch.stack([s1 / 4, xy / s1, xz / s1, a / s1], -1)
    q2 = torch.stack([xy / s2, s2 / 4, yz / s2, b / s2], -1)
    q3 = torch.stack([xz / s3, yz / s3, s3 / 4, c / s3], -1)
    q = torch.where((m11 > m22)[..., None], q2, q3)
    q = torch.where(((m00 > m11) & (m00 > m22))[..., None], q1, q)
    q = torch.where((trace > 0)[..., None], q0, q)
    q = torch.where((q[..., 3] < 0)[..., None], -q, q)
    return q / q.norm(dim=-1, keepdim=True)


def matrix_from_quat(q: torch.Tensor) -> torch.Tensor:
    """(x, y, z, w) quaternions [..., 4], normalised here -> rotation matrices [..., 3, 3]."""
    q = q / q.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    x, y, z, w = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ], -1).reshape(*q.shape[:-1], 3, 3)


@dataclass
class Splats:
    """Gaussians with activated attributes: means [N, 3], colours [N, 3] (linear RGB),
    scales [N, 3], rotations [N, 4] (x, y, z, w), opacities [N]."""

    means: torch.Tensor
    colors: torch.Tensor
    scales: torch.Tensor
    rotations: torch.Tensor
    opacities: torch.Tensor


def base_splats(points: torch.Tensor, colors: torch.Tensor, nbrs: torch.Tensor) -> tuple[Splats, torch.Tensor]:
    """One flat Gaussian per point in its local surface frame: x along the column tangent,
    z along the surface normal; σ = 0.6 × the footprint along the surface, 0.1 × the
    smaller footprint across it. Also returns the frame's normals [N, 3]."""
    u, v, _ = tangents(points, nbrs)
    e1 = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    n = torch.cross(u, v, dim=-1)
    flat = n.norm(dim=-1) <= 1e-6 * u.norm(dim=-1) * v.norm(dim=-1)
    n = torch.where(flat[:, None], _helper_perpendicular(e1), n)
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    e2 = torch.cross(n, e1, dim=-1)
    frame = torch.stack([e1, e2, n], -1)  # columns
    su = u.norm(dim=-1)
    sv = torch.maximum((v * e2).sum(-1).abs(), 0.25 * v.norm(dim=-1))
    scales = torch.stack([SPREAD * su, SPREAD * sv, THICKNESS * torch.minimum(su, sv)], -1)
    splats = Splats(points, colors, scales, quat_from_matrix(frame), torch.full((points.shape[0],), OPACITY))
    return splats, n


def widen(level: int) -> float:
    """How much wider than SPREAD the drawn splats of map size `level` are."""
    return FINE_WIDEN if level > 256 else 1.0


def widened(s: Splats, factor: float) -> Splats:
    """`s` with each splat's two in-surface scales times `factor`."""
    if factor == 1.0:
        return s
    scales = s.scales * torch.tensor([factor, factor, 1.0], dtype=s.scales.dtype)
    return Splats(s.means, s.colors, scales, s.rotations, s.opacities)


@dataclass
class Camera:
    """A pinhole camera in pixels looking like an OrbitCamera (src/render/camera.rs)."""

    rotation: torch.Tensor  # world -> camera [3, 3]
    translation: torch.Tensor  # [3]
    focal: float
    width: int
    height: int
    near: float

    @staticmethod
    def orbit(target, yaw: float, pitch: float, distance: float, width: int, height: int) -> "Camera":
        target = torch.as_tensor(target, dtype=torch.float32)
        eye = target + distance * torch.tensor([math.sin(yaw) * math.cos(pitch), math.sin(pitch), math.cos(yaw) * math.cos(pitch)])
        f = (target - eye) / (target - eye).norm()
        s = torch.linalg.cross(f, torch.tensor([0.0, 1.0, 0.0]))
        s = s / s.norm()
        u = torch.linalg.cross(s, f)
        rotation = torch.stack([s, u, -f])
        focal = 0.5 * height / math.tan(FOV_Y / 2)
        return Camera(rotation, -rotation @ eye, focal, width, height, max(distance * 0.01, 0.01))


def render(splats: Splats, cam: Camera, background: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Differentiable: (image [H, W, 3] linear RGB, alpha [H, W]); the rasterizer's
    projection and blending, without its early stop (transmittance < 1e-4)."""
    t = splats.means @ cam.rotation.T + cam.translation
    z = -t[:, 2]
    keep = z > cam.near
    t, z = t[keep], z[keep]
    cx, cy = 0.5 * cam.width, 0.5 * cam.height
    center = torch.stack([cx + cam.focal * t[:, 0] / z, cy - cam.focal * t[:, 1] / z], -1)
    zero = torch.zeros_like(z)
    j = torch.stack([
        torch.stack([cam.focal / z, zero, cam.focal * t[:, 0] / (z * z)], -1),
        torch.stack([zero, -cam.focal / z, -cam.focal * t[:, 1] / (z * z)], -1),
    ], 1)  # [M, 2, 3]
    m = matrix_from_quat(splats.rotations[keep]) * splats.scales[keep][:, None, :]
    cov = m @ m.transpose(1, 2)
    jw = j @ cam.rotation
    s2 = jw @ cov @ jw.transpose(1, 2) + 0.3 * torch.eye(2)
    a, b, c = s2[:, 0, 0], s2[:, 0, 1], s2[:, 1, 1]
    det = a * c - b * b
    conic = torch.stack([c, -b, a], -1) / det[:, None]
    with torch.no_grad():
        mid = 0.5 * (a + c)
        radius = (3 * (mid + (mid * mid - det).clamp_min(0.1).sqrt()).sqrt()).ceil()
    colors = splats.colors[keep].clamp_min(0)
    opacity = splats.opacities[keep]
    order = torch.argsort(z.detach(), stable=True)
    center, conic, radius, colors, opacity = center[order], conic[order], radius[order], colors[order], opacity[order]

    tiles_x, tiles_y = -(-cam.width // TILE), -(-cam.height // TILE)
    with torch.no_grad():
        c0 = center.detach()
        x0 = ((c0[:, 0] - radius) / TILE).floor().clamp(0, tiles_x)
        x1 = ((c0[:, 0] + radius) / TILE).ceil().clamp(0, tiles_x)
        y0 = ((c0[:, 1] - radius) / TILE).floor().clamp(0, tiles_y)
        y1 = ((c0[:, 1] + radius) / TILE).ceil().clamp(0, tiles_y)
        tx = torch.arange(tiles_x).repeat(tiles_y)
        ty = torch.arange(tiles_y).repeat_interleave(tiles_x)
        cover = (x0[None] <= tx[:, None]) & (tx[:, None] < x1[None]) & (y0[None] <= ty[:, None]) & (ty[:, None] < y1[None])
        counts = cover.sum(1)
        busy = torch.nonzero(counts).squeeze(1)
        # Tiles in order of their splat count, so each chunk pads to a count near its own.
        busy = busy[torch.argsort(counts[busy], stable=True)]
        k = int(counts.max()) if len(busy) else 0
    image = background.expand(cam.height, cam.width, 3).clone()
    alpha_image = torch.zeros(cam.height, cam.width)
    if k == 0:
        return image, alpha_image
    colors_out, alphas_out = [], []
    for chunk in busy.split(TILE_CHUNK):
        k = int(counts[chunk].max())
        c, a = _blend_tiles(chunk, cover, k, tx, ty, center, conic, opacity, colors, background)
        colors_out.append(c)
        alphas_out.append(a)
    color, left = torch.cat(colors_out), torch.cat(alphas_out)
    # Scatter the tiles into the image (tiles past the edge are cropped).
    full = torch.zeros(tiles_y * tiles_x, TILE * TILE, 4)
    full[:, :, :3] = background
    full = full.index_put((busy,), torch.cat([color, (1 - left)[..., None]], -1))
    full = full.reshape(tiles_y, tiles_x, TILE, TILE, 4).permute(0, 2, 1, 3, 4).reshape(tiles_y * TILE, tiles_x * TILE, 4)
    full = full[: cam.height, : cam.width]
    return full[..., :3], full[..., 3]


def _blend_tiles(tiles, cover, k, tx, ty, center, conic, opacity, colors, background):
    """Front-to-back blending of the pixels of `tiles`: (colour [T, 256, 3], the
    transmittance left [T, 256])."""
    with torch.no_grad():
        # Per tile, its splats in depth order first, padded with splats it does not cover.
        rank = torch.argsort((~cover[tiles]).to(torch.int8), dim=1, stable=True)[:, :k]
        valid = torch.gather(cover[tiles], 1, rank)
        py, px = torch.meshgrid(torch.arange(TILE), torch.arange(TILE), indexing="ij")
        px = tx[tiles][:, None] * TILE + px.flatten()[None] + 0.5  # [T, 256]
        py = ty[tiles][:, None] * TILE + py.flatten()[None] + 0.5
    dx = center[rank][:, None, :, 0] - px[:, :, None]  # [T, 256, K]
    dy = center[rank][:, None, :, 1] - py[:, :, None]
    q = conic[rank][:, None]  # [T, 1, K, 3]
    power = -0.5 * (q[..., 0] * dx * dx + q[..., 2] * dy * dy) - q[..., 1] * dx * dy
    alpha = (opacity[rank][:, None] * power.clamp_max(0).exp()).clamp_max(0.99)
    alpha = torch.where((power <= 0) & (alpha >= 1 / 255) & valid[:, None], alpha, torch.zeros_like(alpha))
    trans = torch.cumprod(torch.cat([torch.ones_like(alpha[..., :1]), 1 - alpha[..., :-1]], -1), -1)
    color = (alpha * trans) @ colors[rank]  # [T, 256, 3]
    left = trans[..., -1] * (1 - alpha[..., -1])
    return color + left[..., None] * background, left


def upscale(values: torch.Tensor, pixels: torch.Tensor, size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-pixel values [N, C] of the 128² map's foreground `pixels`, upscaled to a size²
    map as src/splat/upscale.rs does (mask-weighted values and the mask interpolated
    bilinearly, divided, kept where the interpolated mask > 0.25): (pixels [M], [M, C])."""
    mask = torch.zeros(128 * 128)
    mask[pixels] = 1
    maps = torch.zeros(values.shape[1], 128 * 128)
    maps[:, pixels] = values.T
    stack = torch.cat([maps * mask, mask[None]]).reshape(1, -1, 128, 128)
    up = F.interpolate(stack, size=(size, size), mode="bilinear", align_corners=False)[0].flatten(1)
    keep = torch.nonzero(up[-1] > 0.25).squeeze(1)
    return keep, (up[:-1, keep] / up[-1, keep]).T


class Level:
    """Splats at a finer level (as src/engine/appearance.rs): the 128² points, colours and
    any per-point residuals upscaled to the level's map, whose pixels become the splats."""

    def __init__(self, pixels: torch.Tensor, colors: torch.Tensor, size: int):
        self.pixels, self.size = pixels, size
        self.fine, self.colors = upscale(colors, pixels, size)
        self.nbrs = neighbours(self.fine, size)

    def splats(self, points: torch.Tensor, residuals: torch.Tensor | None = None) -> tuple[Splats, torch.Tensor | None]:
        """(base splats at this level, the residuals upscaled to it)."""
        values = points if residuals is None else torch.cat([points, residuals], 1)
        _, up = upscale(values, self.pixels, self.size)
        base, _ = base_splats(up[:, :3], self.colors, self.nbrs)
        return base, (None if residuals is None else up[:, 3:])


def srgb(linear: torch.Tensor) -> torch.Tensor:
    """Linear RGB in [0, 1] -> sRGB-encoded values (what a window shows)."""
    x = linear.clamp(0, 1)
    return torch.where(x <= 0.0031308, 12.92 * x, 1.055 * x.clamp_min(1e-8) ** (1 / 2.4) - 0.055)


def linear(encoded: torch.Tensor) -> torch.Tensor:
    """sRGB-encoded values in [0, 1] -> linear RGB."""
    return torch.where(encoded <= 0.04045, encoded / 12.92, ((encoded + 0.055) / 1.055) ** 2.4)


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    """Peak signal-to-noise ratio in dB of images in [0, 1]."""
    mse = ((a - b) ** 2).mean().item()
    return float("inf") if mse == 0 else -10 * math.log10(mse)


def _window(size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    g = torch.exp(-((torch.arange(size) - size // 2) ** 2) / (2 * sigma**2))
    g = g / g.sum()
    return g[:, None] * g[None, :]


def ssim(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean SSIM of images [H, W, C] in [0, 1] (Wang et al. 2004: 11×11 Gaussian window,
    σ 1.5, C1 = 0.01², C2 = 0.03², valid windows only); differentiable."""
    c1, c2 = 0.01**2, 0.03**2
    x, y = a.permute(2, 0, 1)[:, None], b.permute(2, 0, 1)[:, None]
    w = _window()[None, None]
    mx, my = F.conv2d(x, w), F.conv2d(y, w)
    vx = F.conv2d(x * x, w) - mx * mx
    vy = F.conv2d(y * y, w) - my * my
    cxy = F.conv2d(x * y, w) - mx * my
    s = ((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2))
    return s.mean()
