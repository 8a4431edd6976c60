"""Splats in PyTorch: quaternions, base splats, the differentiable renderer, PSNR, SSIM —
each on cases with known answers."""

import math
from pathlib import Path

import torch

from unica_train import splats as S


def axis_angle(axis, angle):
    a = torch.tensor(axis, dtype=torch.float32)
    a = a / a.norm()
    return torch.cat([a * math.sin(angle / 2), torch.tensor([math.cos(angle / 2)])])


def test_quaternions_survive_the_matrix_round_trip():
    for axis, angle in [((0, 1, 0), 0.7), ((1, 2, -0.5), 2.5), ((1, 0, 0), -1.2), ((0, 0, 1), 3.1), ((1, 1, 0), 3.0)]:
        q = axis_angle(axis, angle)
        q = q if q[3] >= 0 else -q
        got = S.quat_from_matrix(S.matrix_from_quat(q[None]))[0]
        assert torch.allclose(got, q, atol=1e-6), (axis, angle, got, q)
    # A quarter turn about Y takes X to -Z.
    m = S.matrix_from_quat(axis_angle((0, 1, 0), math.pi / 2)[None])[0]
    assert torch.allclose(m @ torch.tensor([1.0, 0, 0]), torch.tensor([0.0, 0, -1]), atol=1e-6)


def flat_patch():
    """A 4 × 3 patch of the front view, spacing 0.01, in the XY plane."""
    rows, cols = torch.meshgrid(torch.arange(10, 13), torch.arange(60, 64), indexing="ij")
    pixels = (rows * 128 + cols).flatten()
    points = torch.stack([cols.flatten() * 0.01, -rows.flatten() * 0.01, torch.full((12,), 0.2)], -1).float()
    return pixels, points


def test_a_flat_grid_gives_discs_in_its_plane_sized_by_the_spacing():
    pixels, points = flat_patch()
    nbrs = S.neighbours(pixels, 128)
    splats, normals = S.base_splats(points, torch.full((12, 3), 0.5), nbrs)
    assert torch.allclose(normals.abs(), torch.tensor([0.0, 0, 1]).expand(12, 3), atol=1e-5)
    assert torch.allclose(splats.scales, torch.tensor([0.006, 0.006, 0.001]).expand(12, 3), atol=1e-6)
    x_axis = S.matrix_from_quat(splats.rotations)[:, :, 0]
    assert torch.allclose(x_axis, torch.tensor([1.0, 0, 0]).expand(12, 3), atol=1e-5)


def test_neighbours_stay_inside_the_view():
    # Column 47 is the back view's last, 48 the front view's first.
    nbrs = S.neighbours(torch.tensor([5 * 128 + 47, 5 * 128 + 48, 5 * 128 + 49]), 128)
    assert nbrs.tolist() == [[-1, -1, -1, -1], [2, -1, -1, -1], [-1, 1, -1, -1]]


def camera():
    return S.Camera.orbit([0.0, 0, 0], 0.0, 0.0, 4.0, 64, 48)


def one_splat(position, color, scale=0.3, opacity=0.9):
    return S.Splats(torch.tensor([position]), torch.tensor([color]), torch.full((1, 3), scale),
                    torch.tensor([[0.0, 0, 0, 1]]), torch.tensor([opacity]))


def test_the_renderer_blends_front_to_back_over_the_background():
    # A red splat in front of a green one: the centre pixel is red·0.9 + green·0.9·0.1 +
    # background·0.01 (as the Rust reference renderer's test).
    front, back = one_splat([0, 0, 0.5], [1.0, 0, 0]), one_splat([0, 0, 0.0], [0.0, 1, 0])
    both = S.Splats(*(torch.cat([getattr(back, f), getattr(front, f)]) for f in ("means", "colors", "scales", "rotations", "opacities")))
    image, alpha = S.render(both, camera(), torch.tensor([0.0, 0, 1]))
    centre = image[24, 32]
    assert torch.allclose(centre, torch.tensor([0.9, 0.09, 0.01]), atol=0.01), centre
    assert torch.equal(image[0, 0], torch.tensor([0.0, 0, 1])) and alpha[0, 0] == 0


def test_the_renderer_passes_gradients_to_every_attribute():
    s = one_splat([0.05, 0.02, 0.0], [0.3, 0.6, 0.2], scale=0.1, opacity=0.7)
    for f in ("means", "colors", "scales", "rotations", "opacities"):
        getattr(s, f).requires_grad_(True)
    s.rotations.data = torch.tensor([[0.1, 0.2, 0.0, 1.0]])
    image, _ = S.render(s, camera(), torch.zeros(3))
    image.sum().backward()
    for f in ("means", "colors", "scales", "rotations", "opacities"):
        assert getattr(s, f).grad.abs().sum() > 0, f


def test_psnr_and_ssim_have_their_known_values():
    a = torch.full((32, 32, 3), 0.5)
    assert math.isinf(S.psnr(a, a))
    assert abs(S.psnr(a, a + 0.1) - 20.0) < 1e-4  # MSE 0.01
    assert abs(S.ssim(a, a).item() - 1) < 1e-6
    # Constant images: only the luminance term is left, (2xy + C1) / (x² + y² + C1)
    # (to 1e-4: f32 windowed variances of a constant are ~1e-8, not 0, against C2 = 9e-4).
    b = torch.full((32, 32, 3), 0.3)
    c1 = 0.01**2
    assert abs(S.ssim(a, b).item() - (2 * 0.5 * 0.3 + c1) / (0.25 + 0.09 + c1)) < 1e-4
    noise = torch.rand(32, 32, 3, generator=torch.Generator().manual_seed(0))
    assert S.ssim(noise, noise * 0.5 + 0.25).item() < S.ssim(noise, noise).item()


def test_srgb_encoding_round_trips():
    x = torch.linspace(0, 1, 101)
    assert torch.allclose(S.linear(S.srgb(x)), x, atol=1e-5)
    assert abs(S.srgb(torch.tensor(0.2140)).item() - 0.5) < 1e-3


def test_the_upscale_keeps_constants_and_grows_the_mask_by_three_quarters_of_a_pixel():
    # A 2×2 block (rows and columns 60-61) of value (1, 2, 3) upscaled ×4 to 512²: every
    # kept pixel is exactly (1, 2, 3); along a row the interpolated mask exceeds 0.25
    # from source x 59.25 to 61.75, i.e. output columns 239..=248 (src/splat/upscale.rs's
    # known answer, moved to this block).
    pixels = torch.tensor([60 * 128 + 60, 60 * 128 + 61, 61 * 128 + 60, 61 * 128 + 61])
    fine, values = S.upscale(torch.tensor([[1.0, 2.0, 3.0]]).expand(4, 3), pixels, 512)
    assert torch.allclose(values, torch.tensor([1.0, 2.0, 3.0]).expand(len(fine), 3))
    row = 4 * 60 + 4
    cols = sorted(int(p) % 512 for p in fine if int(p) // 512 == row)
    assert cols == list(range(239, 249))


def test_a_finer_level_has_more_smaller_splats():
    pixels, points = flat_patch()
    level = S.Level(pixels, torch.full((12, 3), 0.5), 256)
    splats, residuals = level.splats(points, torch.ones(12, 2))
    assert len(level.fine) > 3 * 12 and residuals.shape == (len(level.fine), 2)
    assert torch.allclose(residuals, torch.ones_like(residuals))
    # Inside the patch a fine step is half a pixel: half the footprint (0.6 × 0.005);
    # at its rim the extrapolated values repeat, so splats there are smaller still.
    assert torch.allclose(splats.scales[:, :2].max(0).values, torch.tensor([0.003, 0.003]), atol=1e-5)


def test_splats_above_level_256_are_widened_along_the_surface_only():
    assert S.widen(128) == 1.0 and S.widen(256) == 1.0
    assert S.widen(512) == S.FINE_WIDEN and S.widen(1024) == S.FINE_WIDEN
    # The same constant as the engine's (src/splat/base.rs).
    rust = (Path(__file__).parents[2] / "src/splat/base.rs").read_text()
    assert f"pub const FINE_WIDEN: f32 = {S.FINE_WIDEN};" in rust
    s = S.Splats(torch.zeros(2, 3), torch.zeros(2, 3), torch.tensor([[1.0, 2.0, 0.1], [3.0, 4.0, 0.2]]),
                 torch.tensor([[0.0, 0.0, 0.0, 1.0]] * 2), torch.ones(2))
    w = S.widened(s, 1.5)
    assert torch.equal(w.scales, torch.tensor([[1.5, 3.0, 0.1], [4.5, 6.0, 0.2]]))
    assert S.widened(s, 1.0) is s
