"""The evaluation metrics (docs/architecture.md, Evaluation): generated motion measured against the teacher.

- point clouds: symmetric Chamfer distance, and Chamfer to the nearest of a set of poses;
- distributions: Fréchet distance between Gaussians fitted to feature rows, and sliding
  windows that turn a sequence into such rows;
- world paths ([T, 3] root positions, y up, ground plane x/z): horizontal speed, heading
  (atan2(dx, dz) in degrees: 0° = +Z, 90° = +X), per-key segment summaries, and the
  responsiveness of a key switch (frames until the motion turns to the new heading);
- drift: least-squares slope of a metric over time with its t-distribution 95% interval.

PSNR and SSIM of rendered images live in `splats.py`."""

from __future__ import annotations

import math

import torch
from scipy.spatial import cKDTree

CANDIDATES = 8


def chamfer(a: torch.Tensor, b: torch.Tensor) -> float:
    """Symmetric Chamfer distance between clouds a [N, 3] and b [M, 3]: the mean distance
    from each point of a to its nearest point of b, plus the same from b to a, halved.
    Nearest points come from k-d trees in float64, so distances are exact (a matrix-product
    shortcut in float32 loses millimetres at metre coordinates); all pairs by `cdist` took
    0.5 s for two 4,414-point clouds, most of the quick evaluation's time."""
    a64 = a.detach().to("cpu", torch.float64).numpy()
    b64 = b.detach().to("cpu", torch.float64).numpy()
    a_near, _ = cKDTree(b64).query(a64)
    b_near, _ = cKDTree(a64).query(b64)
    return 0.5 * (float(a_near.mean()) + float(b_near.mean()))


def nearest_pose_chamfer(frame: torch.Tensor, poses: torch.Tensor, centre: bool = True) -> tuple[float, int]:
    """Chamfer distance from frame [N, 3] to the nearest of poses [P, N, 3], and that
    pose's index. With `centre` each cloud's mean is subtracted first, so the comparison is
    of pose, not position. Only the 8 poses with the smallest mean per-point distance (same
    point order) are compared by Chamfer."""
    if centre:
        frame = frame - frame.mean(dim=0)
        poses = poses - poses.mean(dim=1, keepdim=True)
    rough = (poses - frame).norm(dim=-1).mean(dim=-1)
    candidates = rough.topk(min(CANDIDATES, poses.shape[0]), largest=False).indices.tolist()
    return min((chamfer(frame, poses[i]), i) for i in candidates)


def _sqrt_psd(m: torch.Tensor) -> torch.Tensor:
    """Square root of a symmetric positive semi-definite matrix by eigendecomposition."""
    values, vectors = torch.linalg.eigh(m)
    return vectors @ torch.diag(values.clamp(min=0).sqrt()) @ vectors.T


def frechet_distance(x: torch.Tensor, y: torch.Tensor) -> float:
    """Fréchet distance between Gaussians fitted to the rows of x [A, D] and y [B, D]:
    ||mu_x - mu_y||² + Tr(Sx + Sy - 2 (Sx^½ Sy Sx^½)^½), in float64, covariances with the
    unbiased (n - 1) denominator."""
    x, y = x.double(), y.double()
    mu_x, mu_y = x.mean(dim=0), y.mean(dim=0)
    s_x = (x - mu_x).T @ (x - mu_x) / (x.shape[0] - 1)
    s_y = (y - mu_y).T @ (y - mu_y) / (y.shape[0] - 1)
    root_x = _sqrt_psd(s_x)
    middle = root_x @ s_y @ root_x
    cross = _sqrt_psd(0.5 * (middle + middle.T))
    return ((mu_x - mu_y).square().sum() + torch.trace(s_x + s_y - 2 * cross)).item()


def windows(seq: torch.Tensor, length: int = 16, stride: int = 1) -> torch.Tensor:
    """Sliding windows of seq [T, K] as rows [W, length * K], each window flattened frame
    by frame; W = (T - length) // stride + 1."""
    w = seq.unfold(0, length, stride)  # [W, K, length]
    return w.transpose(1, 2).reshape(w.shape[0], length * seq.shape[1])


def _steps(path: torch.Tensor) -> torch.Tensor:
    """Horizontal (x, z) displacement between consecutive frames, [T - 1, 2]."""
    d = path[1:] - path[:-1]
    return d[:, [0, 2]]


def speeds(path: torch.Tensor, frame_rate: float) -> torch.Tensor:
    """Horizontal speed in m/s between consecutive frames of path [T, 3], [T - 1]."""
    return _steps(path).norm(dim=1) * frame_rate


def headings(path: torch.Tensor) -> torch.Tensor:
    """Heading in degrees, atan2(dx, dz), of each step of path [T, 3], [T - 1]."""
    d = _steps(path)
    return torch.rad2deg(torch.atan2(d[:, 0], d[:, 1]))


def heading_difference(a: torch.Tensor | float, b: torch.Tensor | float) -> torch.Tensor:
    """a - b in degrees, wrapped to (-180, 180]."""
    d = torch.remainder(torch.as_tensor(a, dtype=torch.float64) - b, 360.0)
    return torch.where(d > 180.0, d - 360.0, d)


def segment_summary(path: torch.Tensor, keys: list[int], frame_rate: float, settle: int = 15) -> list[dict]:
    """Per run of one action in `keys` (one id per step of path [T, 3]: keys[i] moves
    path[i] to path[i + 1]; 0 Idle, 1 Forward, 2 Backward, 3 Left, 4 Right), for runs longer
    than settle + 5 steps: the action, the run's first step, its length, and over the part
    after the first `settle` steps the mean horizontal speed (m/s) and the heading (degrees)
    of the displacement."""
    if len(keys) != path.shape[0] - 1:
        raise ValueError(f"{len(keys)} keys for a path of {path.shape[0]} frames")
    v = speeds(path, frame_rate)
    out, start = [], 0
    for i in range(1, len(keys) + 1):
        if i < len(keys) and keys[i] == keys[start]:
            continue
        n = i - start
        if n > settle + 5:
            first = start + settle
            heading = headings(torch.stack([path[first], path[i]]))[0].item()
            out.append({"action": keys[start], "start": start, "frames": n, "speed": v[first:i].mean().item(), "heading": heading})
        start = i
    return out


def turn_frames(path: torch.Tensor, switch: int, target_heading: float, tolerance: float = 10.0, min_step: float = 1e-3) -> int | None:
    """Responsiveness of a key switch, as the UNICA paper measures it. Frame `switch` is the
    first frame generated under the new key; a frame is on target when the step into it
    (path[f - 1] -> path[f]) is at least `min_step` metres long horizontally and its heading
    is within `tolerance` degrees of `target_heading`. Returns the number of frames under
    the new key up to and including the first frame f >= switch that is on target together
    with the next 3 frames (f - switch + 1; 1 means the first new frame already moves the
    new way), or None if there is no such frame."""
    d = _steps(path)
    on = (d.norm(dim=1) >= min_step) & (heading_difference(headings(path), target_heading).abs() <= tolerance)
    # on[j] is the step into frame j + 1.
    for f in range(max(switch, 1), path.shape[0] - 3):
        if on[f - 1 : f + 3].all():
            return f - switch + 1
    return None


def _betainc(a: float, b: float, x: float) -> float:
    """Regularised incomplete beta function I_x(a, b) by its continued fraction (modified
    Lentz), evaluated on the side of x where it converges fast."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    if x > (a + 1.0) / (a + b + 2.0):
        return 1.0 - _betainc(b, a, 1.0 - x)
    tiny = 1e-300
    front = math.exp(math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)) / a
    c, d = 1.0, 1.0 - (a + b) * x / (a + 1.0)
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 500):
        for numerator in (
            m * (b - m) * x / ((a + 2 * m - 1) * (a + 2 * m)),
            -(a + m) * (a + b + m) * x / ((a + 2 * m) * (a + 2 * m + 1)),
        ):
            d = 1.0 + numerator * d
            d = 1.0 / (d if abs(d) > tiny else tiny)
            c = 1.0 + numerator / c
            c = c if abs(c) > tiny else tiny
            h *= c * d
        if abs(c * d - 1.0) < 1e-15:
            break
    return front * h


def student_t_cdf(t: float, df: float) -> float:
    """P(T <= t) for Student's t with `df` degrees of freedom."""
    tail = 0.5 * _betainc(0.5 * df, 0.5, df / (df + t * t))
    return 1.0 - tail if t > 0 else tail


def student_t_quantile(p: float, df: float) -> float:
    """The t such that P(T <= t) = p, by bisection on the CDF."""
    if p < 0.5:
        return -student_t_quantile(1.0 - p, df)
    hi = 1.0
    while student_t_cdf(hi, df) < p:
        hi *= 2.0
    lo = 0.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if student_t_cdf(mid, df) < p else (lo, mid)
    return 0.5 * (lo + hi)


def drift_slope(values: torch.Tensor, window_starts: torch.Tensor) -> dict:
    """Least-squares line values = a + b · window_starts over W >= 3 windows: {"slope": b,
    "ci95": (lo, hi)}, the 95% interval from the residual standard error and Student's t
    with W - 2 degrees of freedom."""
    y, x = values.double(), window_starts.double()
    w = x.shape[0]
    if w < 3:
        raise ValueError(f"a drift slope needs at least 3 windows, got {w}")
    xc = x - x.mean()
    sxx = xc.square().sum()
    slope = (xc * (y - y.mean())).sum() / sxx
    residuals = y - y.mean() - slope * xc
    se = (residuals.square().sum() / (w - 2) / sxx).sqrt().item()
    half = student_t_quantile(0.975, w - 2) * se
    b = slope.item()
    return {"slope": b, "ci95": (b - half, b + half)}


# ---- masked image metrics (issue #17) ---------------------------------------------------


def union_box(a_alpha: torch.Tensor, b_alpha: torch.Tensor, threshold: float = 1 / 255) -> tuple[int, int, int, int] | None:
    """The smallest box (y0, y1, x0, x1; ends exclusive) holding both images' foreground
    (alpha above `threshold`); None when neither has any."""
    fg = (a_alpha > threshold) | (b_alpha > threshold)
    rows, cols = fg.any(1).nonzero(), fg.any(0).nonzero()
    if rows.numel() == 0:
        return None
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def masked_scores(got: torch.Tensor, want: torch.Tensor, background: float) -> tuple[float, float]:
    """(PSNR dB, SSIM) of two premultiplied linear RGBA images [H, W, 4] composited on a
    grey level `background` (0 black, 1 white) and sRGB-encoded, over the union of their
    foreground boxes only, so an empty background cannot pad the score. A box thinner than
    the SSIM window (11 px) is widened to it inside the image."""
    from .splats import psnr, srgb, ssim

    box = union_box(got[..., 3], want[..., 3])
    if box is None:
        return float("inf"), 1.0
    y0, y1, x0, x1 = box
    h, w = got.shape[:2]
    if y1 - y0 < 11:
        y0 = max(0, min(y0, h - 11)); y1 = y0 + 11
    if x1 - x0 < 11:
        x0 = max(0, min(x0, w - 11)); x1 = x0 + 11

    def shown(img):
        return srgb(img[y0:y1, x0:x1, :3] + (1 - img[y0:y1, x0:x1, 3:]) * background)

    a, b = shown(got), shown(want)
    return psnr(a, b), ssim(a, b).item()


def stop_frames(path: torch.Tensor, release: int, frame_rate: float, below: float = 0.05) -> tuple[int | None, float]:
    """After the keys are released at frame `release` (the first idle step is path[release]
    -> path[release + 1]): the number of frames until the root's horizontal speed is below
    `below` m/s for good (0: already from the first idle step; None: never), and the
    horizontal distance travelled from the release to the end of the path (m)."""
    v = speeds(path[release:], frame_rate)
    moving = (v >= below).nonzero()
    frames = 0 if moving.numel() == 0 else int(moving[-1]) + 1
    if frames == v.shape[0]:
        frames = None
    d = path[-1] - path[release]
    return frames, float(torch.stack([d[0], d[2]]).norm())


def yaw_align(frame: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
    """The rotation angle θ (radians, about +Y) that best maps root-centred `frame` [N, 3]
    onto `pose` [N, 3] point for point (least squares in the XZ plane): rotate frame by
    x' = x cos θ + z sin θ, z' = -x sin θ + z cos θ."""
    x, z, px, pz = frame[:, 0], frame[:, 2], pose[:, 0], pose[:, 2]
    return torch.atan2((x * pz - z * px).sum() * -1, (x * px + z * pz).sum())


def rotate_y(points: torch.Tensor, theta: torch.Tensor | float) -> torch.Tensor:
    """Points [..., 3] rotated by θ about +Y as `yaw_align` defines it."""
    t = torch.as_tensor(theta, dtype=points.dtype)
    c, s = torch.cos(t), torch.sin(t)
    x, y, z = points.unbind(-1)
    return torch.stack([x * c + z * s, y, -x * s + z * c], -1)


def nearest_aligned_pose(frame: torch.Tensor, poses: torch.Tensor) -> tuple[float, int, float]:
    """(Chamfer distance, index, yaw θ) of the nearest of root-centred `poses` [P, N, 3] to
    root-centred `frame` [N, 3] after turning the frame by each pose's best yaw
    (`yaw_align`): the 8 poses nearest point for point are compared by Chamfer."""
    x, z = frame[:, 0], frame[:, 2]
    px, pz = poses[..., 0], poses[..., 2]
    thetas = torch.atan2((px * z - pz * x).sum(1), (px * x + pz * z).sum(1))  # yaw_align for each pose
    c, s = torch.cos(thetas)[:, None], torch.sin(thetas)[:, None]
    x, y, z = frame[:, 0], frame[:, 1], frame[:, 2]
    turned = torch.stack([x * c + z * s, y.expand_as(c * x), -x * s + z * c], -1)  # [P, N, 3]
    rough = (poses - turned).norm(dim=-1).mean(dim=-1)
    candidates = rough.topk(min(CANDIDATES, poses.shape[0]), largest=False).indices.tolist()
    best = min((chamfer(turned[i], poses[i]), i) for i in candidates)
    return best[0], best[1], float(thetas[best[1]])
