"""Latent recentring (unica_train.recentre): the shift basis is exact for an affine encoder
and first-order exact for the VAE's encoder; the rollout's "reencode" mode is train.py's
reference loop and its "latent" mode never calls the encoder; the root motion measured
from the decoded last context latent cancels a root bias both frames share; the canonical
heading turns the window and the keys to W's direction; grounded, the root's height
stands the lowest point on the floor."""

import pytest
import torch

from unica_train import recentre
from unica_train.dataset import BakedDataset
from unica_train.diffusion import Schedule
from unica_train.train import Run, TrainConfig, parse_keys
from unica_train.unet import UNet, UNetConfig
from unica_train.vae import PositionVae, VaeConfig

TINY_VAE = VaeConfig(channels=(16, 12, 8, 8))
TINY_UNET = UNetConfig(channels=(16, 32), embed=32, heads=2)


def layout(n=600, seed=0):
    g = torch.Generator().manual_seed(seed)
    pixels = torch.randperm(128 * 128, generator=g)[:n].sort().values
    return pixels, torch.arange(0, n, 7), g


def test_basis_is_exact_for_an_affine_encoder():
    pixels, _, g = layout()
    conv = torch.nn.Conv2d(3, 4, 8, stride=8)
    encode = lambda x: conv(x).detach() * 1.7  # noqa: E731
    refs = recentre.to_maps(torch.rand(2, pixels.shape[0], 3, generator=g), pixels)
    J = recentre.shift_basis(encode, refs, pixels, step=0.05)
    assert J.shape == (3, 4, 16, 16)
    x = recentre.to_maps(torch.rand(pixels.shape[0], 3, generator=g), pixels)
    delta = torch.tensor([0.03, -0.01, 0.07])
    exact = encode((x - delta[:, None, None] * recentre.mask(pixels))[None])[0]
    approx = recentre.apply_shift(encode(x[None])[0], delta, J)
    assert torch.allclose(approx, exact, atol=1e-5)
    # one-sided differences agree for an affine map too
    assert torch.allclose(recentre.shift_basis(encode, refs, pixels, step=0.05, central=False), J, atol=1e-4)


def test_basis_is_first_order_exact_for_the_vae_encoder():
    torch.manual_seed(0)
    pixels, _, g = layout()
    vae = PositionVae(TINY_VAE).eval()
    encode = recentre.encoder_fn(vae, 1.3)
    x = recentre.to_maps(0.3 + 0.4 * torch.rand(1, pixels.shape[0], 3, generator=g, dtype=torch.float64), pixels)
    vae.double()
    J = recentre.shift_basis(encode, x, pixels, step=1e-4)  # the tangent at x
    m = recentre.mask(pixels).double()
    direction = torch.tensor([0.8, -0.2, 0.56], dtype=torch.float64)
    errors = []
    for size in (0.08, 0.04, 0.02):
        delta = direction * size
        exact = encode(x - delta[:, None, None] * m)[0]
        approx = recentre.apply_shift(encode(x)[0], delta, J)
        errors.append(float((approx - exact).abs().max()))
    # second-order remainder: halving δ quarters the error
    assert 3.0 < errors[0] / errors[1] < 5.0 and 3.0 < errors[1] / errors[2] < 5.0, errors


def test_maps_round_trip_and_keys_text():
    pixels, waist, g = layout()
    pts = torch.rand(2, pixels.shape[0], 3, generator=g)
    assert torch.equal(recentre.from_maps(recentre.to_maps(pts, pixels), pixels), pts)
    assert torch.allclose(recentre.root(pts, waist), pts[:, waist].mean(1))
    assert recentre.keys_text(parse_keys("3W 2A 1I", 6)) == "3W 2A 1I"


def tiny_models():
    torch.manual_seed(1)
    return PositionVae(TINY_VAE).eval(), UNet(TINY_UNET).eval(), Schedule()


def test_reencode_mode_is_the_reference_rollout(quick_dataset_dir, tmp_path):
    vae, unet, schedule = tiny_models()
    cfg = TrainConfig(rollout_keys="2W 1A", rollout_frames=3, ddim_steps=2, seed=3)
    run = Run(quick_dataset_dir, tmp_path, cfg, torch.device("cpu"))
    want = run.rollout(vae, unet, schedule, 1.1)
    ds = BakedDataset(quick_dataset_dir)
    unit, start = ds.normalise(run.world[0][0:4])
    context = vae.encoder(ds.to_maps(unit[:3]))[0].detach() * 1.1
    got = recentre.rollout(vae, unet, schedule, 1.1, context, "2W 1A", 2, 1.0, 3, ds.pixels, ds.waist, ds.scale,
                           "reencode", frames=3, window=unit[:3], start_root=start)
    assert got["keys"] == want["keys"] and got["frames"] == 3
    assert torch.allclose(torch.tensor(got["root_path"]), torch.tensor(want["root_path"]), atol=1e-5)


def test_latent_mode_never_encodes():
    vae, unet, schedule = tiny_models()
    pixels, waist, g = layout()
    calls = []
    vae.encoder.register_forward_hook(lambda *_: calls.append(1))
    context = torch.randn(3, 4, 16, 16, generator=g)
    basis = torch.randn(3, 4, 16, 16, generator=g) * 0.1
    out = recentre.rollout(vae, unet, schedule, 1.0, context, "2W 1S", 2, 1.0, 0, pixels, waist, 0.35, "latent", basis=basis)
    assert calls == [] and len(out["root_path"]) == 4 and len(out["shifts"]) == 3
    recentre.rollout(vae, unet, schedule, 1.0, context, "2W", 2, 1.0, 0, pixels, waist, 0.35, "reencode")
    assert len(calls) == 2  # the reference re-encodes every frame


def repeating_frame(monkeypatch):
    """Tiny models, a layout and random context latents, with a sampler that gives back the
    context's last latent: every new frame is that latent decoded (`new`, clamped)."""
    vae, unet, schedule = tiny_models()
    pixels, waist, g = layout()
    monkeypatch.setattr(recentre, "sample_next", lambda unet, schedule, context, *a, **k: context[:, -1])
    context = torch.randn(3, 4, 16, 16, generator=g)
    new = recentre.decode_points(vae, context[-1:], 1.0, pixels)[0].clamp(0.0, 1.0)
    return vae, unet, schedule, pixels, waist, context, new


def test_decoded_root_motion_cancels_a_bias_the_two_frames_share(monkeypatch):
    # A UNet that gives back the context's last latent: every new frame decodes to the
    # same map as that latent. Measured from the centre the world root moves by that
    # map's root - 0.5 every frame; measured from the decoded last latent it stays put,
    # and the drawn points are the frame root-centred at the world root either way.
    vae, unet, schedule, pixels, waist, context, new = repeating_frame(monkeypatch)
    bias = recentre.root(new, waist) - 0.5
    assert float(bias.abs().max()) > 1e-3
    runs = {mode: recentre.rollout(vae, unet, schedule, 1.0, context, "3W", 2, 1.0, 0, pixels, waist, 0.5, "none",
                                   root_motion=mode) for mode in ("centre", "decoded")}
    centre, decoded = (torch.tensor(runs[m]["root_path"]) for m in ("centre", "decoded"))
    assert torch.allclose(centre[3] - centre[0], 3 * bias / 0.5, atol=1e-5)
    assert torch.allclose(decoded, torch.zeros(4, 3), atol=1e-6)
    drawn = torch.tensor(runs["decoded"]["sampled_points"][0])
    assert torch.allclose(drawn, (new - recentre.root(new, waist)) / 0.5, atol=1e-5)
    with pytest.raises(ValueError, match="root_motion"):
        recentre.rollout(vae, unet, schedule, 1.0, context, "1W", 2, 1.0, 0, pixels, waist, 0.5, "none", root_motion="x")


def test_turn_unit_turns_about_the_centre_as_the_dataset_does():
    # One quarter turn takes (x, y, z) to (z, y, 1 - x) about x = z = 0.5 (+Z to +X, the
    # engine's quarter_turn.wgsl known answer); four turns or none leave a point alone.
    p = torch.tensor([[0.2, 0.5, 0.1], [0.5, 0.3, 0.5]])
    assert torch.allclose(recentre.turn_unit(p, 1), torch.tensor([[0.1, 0.5, 0.8], [0.5, 0.3, 0.5]]))
    assert torch.allclose(recentre.turn_unit(p, 3), torch.tensor([[0.9, 0.5, 0.2], [0.5, 0.3, 0.5]]))
    assert torch.equal(recentre.turn_unit(p, 0), p)
    assert torch.allclose(recentre.turn_unit(p, 4), p)
    assert torch.allclose(recentre.turn_unit(recentre.turn_unit(p, 1), 3), p)


def test_heading_quarters_follow_the_last_movement_key():
    W, S, A, D = 1, 2, 3, 4
    assert recentre.heading_quarters([W, A, 0, 0], "canonical") == 1
    assert recentre.heading_quarters([W, S], "canonical") == 2
    assert recentre.heading_quarters([A, D, 0], "canonical") == 3
    assert recentre.heading_quarters([0, 0], "canonical") == 0
    assert recentre.heading_quarters([A, D], "world") == 0


def test_the_canonical_heading_shows_the_model_w_and_the_window_turned(monkeypatch):
    # A sampler that records what it is given and returns the context's last latent.
    # With the canonical heading every held key reaches the model as W (Idle stays
    # Idle), and the context it gets under A is the window turned three quarter turns
    # (A's one turned back) and encoded; with the world's heading the keys pass as they
    # are and the first context is the window encoded as it is.
    vae, unet, schedule = tiny_models()
    pixels, waist, g = layout()
    seen = []

    def fake(unet, schedule, context, action, *a, **k):
        seen.append((int(action[0]), context[0].clone()))
        return context[:, -1]

    monkeypatch.setattr(recentre, "sample_next", fake)
    context = torch.randn(3, 4, 16, 16, generator=g)
    window = 0.3 + 0.4 * torch.rand(3, pixels.shape[0], 3, generator=g)
    encode = recentre.encoder_fn(vae, 1.0)
    for heading, want in (("canonical", [1, 1, 0, 1, 1]), ("world", [3, 3, 0, 2, 4])):
        seen.clear()
        recentre.rollout(vae, unet, schedule, 1.0, context, "1A 1A 1I 1S 1D", 2, 1.0, 0, pixels, waist, 0.5,
                         "reencode", window=window, heading=heading)
        assert [a for a, _ in seen] == want, heading
        turns = 3 if heading == "canonical" else 0
        first = encode(recentre.to_maps(recentre.turn_unit(window, turns), pixels))
        assert torch.allclose(seen[0][1], first, atol=1e-5), heading
    with pytest.raises(ValueError, match="heading"):
        recentre.rollout(vae, unet, schedule, 1.0, context, "1W", 2, 1.0, 0, pixels, waist, 0.5, "latent",
                         basis=context, heading="canonical")
    with pytest.raises(ValueError, match="heading"):
        recentre.rollout(vae, unet, schedule, 1.0, context, "1W", 2, 1.0, 0, pixels, waist, 0.5, "reencode",
                         heading="sideways")


def test_grounded_height_stands_the_lowest_point_on_the_floor(monkeypatch):
    # The same frame every time (the sampler gives back the context's last latent):
    # integrated, the world root's height moves by the frame's root - 0.5 each frame;
    # grounded, it is (root - lowest point) / norm_scale after every frame, whatever came
    # before, and the horizontal path is the integrated one.
    vae, unet, schedule, pixels, waist, context, new = repeating_frame(monkeypatch)
    runs = {flag: torch.tensor(recentre.rollout(vae, unet, schedule, 1.0, context, "3W", 2, 1.0, 0, pixels, waist, 0.5,
                                                "none", grounded=flag, start_root=torch.tensor([0.0, 7.0, 0.0]))["root_path"])
            for flag in (False, True)}
    height = (recentre.root(new, waist)[1] - new[:, 1].min()) / 0.5
    assert float(height) > 0.1
    assert torch.allclose(runs[True][1:, 1], height.expand(3), atol=1e-5)
    assert torch.allclose(runs[False][3, 1] - runs[False][0, 1], 3 * (recentre.root(new, waist)[1] - 0.5) / 0.5, atol=1e-5)
    assert torch.allclose(runs[True][:, [0, 2]], runs[False][:, [0, 2]], atol=1e-6)


def test_the_stand_latch_holds_the_root_under_idle_until_a_key(monkeypatch):
    # The same frame every time: every frame's motion is the same bias. With the latch
    # above the bias's speed, the root moves under W and holds under Idle (the first Idle
    # frame is slow enough, the next ones are held); a key releases it. Below that speed
    # the latch never holds, and the path is the one without it. The height is the
    # integrated one either way.
    vae, unet, schedule, pixels, waist, context, new = repeating_frame(monkeypatch)
    bias = recentre.root(new, waist) - 0.5
    speed = float(torch.hypot(bias[0], bias[2])) / 0.5 * 30.0  # m/s at norm_scale 0.5, 30 fps
    assert speed > 1e-2

    def path(stand):
        return torch.tensor(recentre.rollout(vae, unet, schedule, 1.0, context, "2W 3I 1W 1I", 2, 1.0, 0, pixels, waist,
                                             0.5, "none", stand_speed=stand)["root_path"])

    free, held, loose = path(None), path(2 * speed), path(speed / 2)
    assert torch.allclose(loose, free, atol=1e-6)
    step = bias / 0.5
    moved = [1, 2, 2, 2, 2, 3, 3]  # horizontal steps taken after each of the 7 frames
    for f, n in enumerate(moved, start=1):
        assert torch.allclose(held[f, [0, 2]], n * step[[0, 2]], atol=1e-5), f
        assert torch.allclose(held[f, 1], free[f, 1], atol=1e-6)
