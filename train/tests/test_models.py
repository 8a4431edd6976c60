"""Shapes, budgets and known answers for the VAE, UNet and the diffusion maths."""

import torch

from unica_train.diffusion import (Schedule, brake_options, ddim_step, frame_cfg_scales, frame_idle_scales, frame_options,
                                   guided_eps, idle_scale, turn_brake_options, turn_runs,
                                   sample_next, sampler_options, step_scales)
from unica_train.unet import UNet, UNetConfig, conv_and_linear_flops, parameter_count
from unica_train.vae import PositionVae, VaeConfig


def test_vae_shapes_and_decoder_budget():
    vae = PositionVae()
    x = torch.rand(2, 3, 128, 128)
    z, mean, logvar = vae.encode(x)
    assert z.shape == (2, 4, 16, 16)
    assert vae.decode(z).shape == (2, 3, 128, 128)
    flops = conv_and_linear_flops(vae.decoder, z[:1])
    assert flops <= 0.5e9, f"decoder {flops / 1e9:.3f} GFLOP"


def test_unet_shapes_budget_and_zero_start():
    unet = UNet()
    x = torch.randn(1, 4, 4, 16, 16)
    t = torch.tensor([[0, 0, 0, 500]])
    with torch.no_grad():
        out = unet(x, t, torch.tensor([1]))
    assert out.shape == x.shape
    assert float(out.abs().max()) == 0.0, "the output layer starts at zero"
    # Per frame of the group: at most 1 GFLOP per UNet step for the frame generated.
    per_frame = conv_and_linear_flops(unet, x, t, torch.tensor([1])) / 4
    assert per_frame <= 1e9, f"{per_frame / 1e9:.3f} GFLOP per frame"
    assert parameter_count(unet) < 20e6


def test_temporal_attention_is_causal():
    torch.manual_seed(0)
    unet = UNet(UNetConfig(channels=(16, 32), embed=32, heads=2))
    torch.nn.init.normal_(unet.conv_out.weight, std=0.1)
    x = torch.randn(1, 4, 4, 16, 16)
    t = torch.tensor([[0, 0, 0, 900]])
    with torch.no_grad():
        a = unet(x, t, torch.tensor([2]))
    x2 = x.clone()
    x2[:, 3] = torch.randn(4, 16, 16)  # a different noisy target
    with torch.no_grad():
        b = unet(x2, torch.tensor([[0, 0, 0, 100]]), torch.tensor([2]))
    torch.testing.assert_close(a[:, :3], b[:, :3], rtol=0, atol=1e-6)
    assert not torch.allclose(a[:, 3], b[:, 3])


def test_schedule_endpoints_and_min_snr():
    s = Schedule()
    a = s.alphas_cumprod
    assert abs(float(a[0]) - (1 - 0.00085)) < 1e-7
    assert 0.004 < float(a[-1]) < 0.006  # the SD-1.5 schedule ends near 0.0047
    w = s.min_snr_weight(torch.tensor([0, 999]))
    assert float(w[1]) == 1.0 and float(w[0]) < 0.01


def test_ddim_recovers_a_point_mass_exactly():
    # Data is the single point x0: the exact eps at x_t is (x_t - sqrt(ab) x0) / sqrt(1 - ab).
    s = Schedule()
    x0 = torch.full((1, 4, 16, 16), 0.3)

    class Oracle(torch.nn.Module):
        cfg = UNetConfig()

        def forward(self, latents, t_frames, action):
            t = int(t_frames[0, -1])
            ab = s.alpha_bar(torch.tensor(t))
            eps = (latents[:, -1] - ab.sqrt() * x0) / (1 - ab).sqrt()
            return torch.stack([eps] * 4, 1)

    noise = torch.randn(1, 4, 16, 16, generator=torch.Generator().manual_seed(1))
    for steps in (1, 4, 10):
        out = sample_next(Oracle(), s, torch.zeros(1, 3, 4, 16, 16), torch.tensor([1]), steps=steps, noise=noise)
        torch.testing.assert_close(out, x0, atol=1e-4, rtol=0)
    # One step from t to -1 with the true eps lands on x0 too.
    xt = s.add_noise(x0, noise, torch.tensor([700]))
    eps = (xt - s.alpha_bar(torch.tensor(700)).sqrt() * x0) / (1 - s.alpha_bar(torch.tensor(700))).sqrt()
    torch.testing.assert_close(ddim_step(s, xt, eps, 700, -1), x0, atol=1e-5, rtol=0)


def test_a_guidance_interval_guides_only_the_first_steps():
    assert step_scales(4, 3.0) == [3.0, 3.0, 3.0, 3.0]
    assert step_scales(4, 3.0, 2) == [3.0, 3.0, 1.0, 1.0]
    assert step_scales(4, 3.0, 0) == [1.0] * 4
    assert step_scales(4, 3.0, 9) == [3.0] * 4
    s = Schedule()

    class Keyed(torch.nn.Module):
        # eps = 0.5 x_t + 0.2 under action 1, 0.5 x_t under the null action (5).
        cfg = UNetConfig()

        def forward(self, latents, t_frames, action):
            eps = 0.5 * latents[:, -1] + 0.2 * (action == 1).float()[:, None, None, None]
            return torch.stack([eps] * 4, 1)

    noise = torch.randn(1, 4, 16, 16, generator=torch.Generator().manual_seed(2))
    got = sample_next(Keyed(), s, torch.zeros(1, 3, 4, 16, 16), torch.tensor([1]), steps=4, cfg_scale=3.0, noise=noise,
                      guided_steps=2)
    x, times = noise.clone(), s.ddim_timesteps(4)
    for i, t in enumerate(times):
        eps = 0.5 * x + 0.2 * (3.0 if i < 2 else 1.0)  # null + s (cond - null)
        x = ddim_step(s, x, eps, t, times[i + 1] if i + 1 < 4 else -1)
    torch.testing.assert_close(got, x, atol=1e-5, rtol=0)
    every = sample_next(Keyed(), s, torch.zeros(1, 3, 4, 16, 16), torch.tensor([1]), steps=4, cfg_scale=3.0, noise=noise)
    assert (every - got).abs().max() > 0.01


def test_an_unguided_idle_takes_the_conditional_prediction_and_the_noise_scales():
    class Keyed(torch.nn.Module):
        # eps = 0.5 x_t + 0.1 × (action id + 1): Idle (0) 0.1, Forward (1) 0.2, null (5) 0.6.
        cfg = UNetConfig()

        def forward(self, latents, t_frames, action):
            eps = 0.5 * latents[:, -1] + 0.1 * (action.float() + 1)[:, None, None, None]
            return torch.stack([eps] * 4, 1)

    x = torch.randn(3, 4, 4, 16, 16, generator=torch.Generator().manual_seed(3))
    t = torch.tensor([[0, 0, 0, 500]] * 3)
    action = torch.tensor([0, 1, 0])
    base = 0.5 * x[:, -1]
    guided = guided_eps(Keyed(), x, t, action, 4.0)
    # null + s (cond - null): Idle 0.6 + 4 (0.1 - 0.6) = -1.4, Forward 0.6 + 4 (0.2 - 0.6) = -1.0.
    for i, want in enumerate([-1.4, -1.0, -1.4]):
        torch.testing.assert_close(guided[i] - base[i], torch.full_like(base[i], want), atol=1e-5, rtol=0)
    unguided = guided_eps(Keyed(), x, t, action, 4.0, guide_idle=False)
    for i, want in enumerate([0.1, -1.0, 0.1]):
        torch.testing.assert_close(unguided[i] - base[i], torch.full_like(base[i], want), atol=1e-5, rtol=0)
    # The starting noise: standard normal times noise_scale, from the same generator.
    s, context = Schedule(), torch.zeros(1, 3, 4, 16, 16)
    half = sample_next(Keyed(), s, context, torch.tensor([1]), steps=2, cfg_scale=4.0, noise_scale=0.5,
                       generator=torch.Generator().manual_seed(4))
    drawn = 0.5 * torch.randn(1, 4, 16, 16, generator=torch.Generator().manual_seed(4))
    torch.testing.assert_close(half, sample_next(Keyed(), s, context, torch.tensor([1]), steps=2, cfg_scale=4.0, noise=drawn))
    # An Idle scale of its own: Idle 0.6 + 1.5 (0.1 - 0.6) = -0.15, Forward as before; it
    # overrides guide_idle, and an unguided step leaves every sample unguided.
    own = guided_eps(Keyed(), x, t, action, 4.0, guide_idle=False, idle_cfg_scale=1.5)
    for i, want in enumerate([-0.15, -1.0, -0.15]):
        torch.testing.assert_close(own[i] - base[i], torch.full_like(base[i], want), atol=1e-5, rtol=0)
    assert [idle_scale(4.0), idle_scale(4.0, False), idle_scale(4.0, False, 1.5), idle_scale(1.0, True, 1.5)] == [4.0, 1.0, 1.5, 1.0]
    # Old manifests guide Idle at noise scale 1.
    assert sampler_options({"ddim_steps": 10, "cfg_scale": 4.0}) == {"guide_idle": True, "noise_scale": 1.0, "idle_cfg_scale": None}
    assert sampler_options({"guide_idle": False, "noise_scale": 0.5, "idle_cfg_scale": 1.5}) == {
        "guide_idle": False, "noise_scale": 0.5, "idle_cfg_scale": 1.5}


def test_the_first_idle_frames_after_a_key_brake():
    # Ids: Idle 0, W 1, S 2. Two Idle frames before any key (a standing start: not
    # braked), W, three Idle (two braked), S, one Idle (braked).
    actions = [0, 0, 1, 0, 0, 0, 2, 0]
    assert frame_idle_scales(actions, 1.5, 2.0, 2) == [1.5, 1.5, 1.5, 2.0, 2.0, 1.5, 1.5, 2.0]
    # No braking: every frame at the Idle scale (None: the sampler's own rule).
    assert frame_idle_scales(actions, None) == [None] * 8
    assert frame_idle_scales(actions, 1.5, 2.0, 0) == [1.5] * 8
    # The manifest's settings, and none in an older bundle.
    assert brake_options({"idle_brake_cfg_scale": 2, "idle_brake_frames": 10}) == {
        "idle_brake_cfg_scale": 2.0, "idle_brake_frames": 10}
    assert brake_options({}) == {"idle_brake_cfg_scale": None, "idle_brake_frames": 0}
    # A teacher-forced frame's options: the last frame of its clip's keys so far.
    options = {"guide_idle": False, "noise_scale": 0.25, "idle_cfg_scale": 1.5}
    brake = {"idle_brake_cfg_scale": 2.0, "idle_brake_frames": 2}
    assert frame_options(options, brake, [1, 0]) == dict(options, idle_cfg_scale=2.0)
    assert frame_options(options, brake, [1, 0, 0, 0]) == options
    assert frame_options(options, brake, [0, 0]) == options


def test_the_first_frames_of_a_turn_brake():
    # The engine's the_first_frames_of_a_turn_brake. Ids: Idle 0, W 1, S 2, A 3, D 4. W
    # from rest (no turn), D (a turn), Idle, D again (no turn), A, Idle, S.
    actions = [1, 1, 4, 4, 4, 0, 0, 4, 3, 3, 3, 0, 2]
    assert turn_runs(actions) == [None, None, 1, 2, 3, None, None, None, 1, 2, 3, None, 1]
    assert frame_cfg_scales(actions, 2.0, 1.25, 2) == [2.0, 2.0, 1.25, 1.25, 2.0, 2.0, 2.0, 2.0, 1.25, 1.25, 2.0, 2.0, 1.25]
    # No braking without the setting, with no frames, or in an unguided sampler.
    assert frame_cfg_scales(actions, 2.0) == [2.0] * 13
    assert frame_cfg_scales(actions, 2.0, 1.25, 0) == [2.0] * 13
    assert frame_cfg_scales(actions, 1.0, 1.25, 2) == [1.0] * 13
    # The manifest's settings, and none in an older bundle.
    assert turn_brake_options({"turn_brake_cfg_scale": 1.25, "turn_brake_frames": 8}) == {
        "turn_brake_cfg_scale": 1.25, "turn_brake_frames": 8}
    assert turn_brake_options({}) == {"turn_brake_cfg_scale": None, "turn_brake_frames": 0}


def test_vae_loss_falls_on_an_overfit_batch():
    torch.manual_seed(0)
    vae = PositionVae(VaeConfig(channels=(16, 12, 8, 8)))
    x = torch.rand(2, 3, 128, 128)
    mask = (torch.rand(1, 1, 128, 128) > 0.7).float()
    x = x * mask
    opt = torch.optim.Adam(vae.parameters(), lr=3e-3)
    first = None
    for _ in range(60):
        loss, _ = vae.loss(x, mask, generator=torch.Generator().manual_seed(0))
        first = first if first is not None else loss.item()
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert loss.item() < 0.5 * first, f"{first} -> {loss.item()}"


def test_the_pca_head_decoder_gives_its_maps_back():
    # Maps whose foreground values lie in a 3-dimensional affine subspace: a basis of 3
    # components fits them, a head whose bias holds one map's coefficients decodes that
    # map from any latent, the background is 0, and a zero head decodes the mean.
    gen = torch.Generator().manual_seed(0)
    pixels = torch.tensor([3, 40, 41, 200, 1000])
    directions, offset = torch.randn(3, 15, generator=gen), torch.randn(15, generator=gen)
    values = offset + torch.randn(12, 3, generator=gen) @ directions  # [12, 3P]
    maps = torch.zeros(12, 3, 32 * 32)
    maps[:, :, pixels] = values.view(12, 3, 5)
    maps = maps.view(12, 3, 32, 32)
    vae = PositionVae(VaeConfig(channels=(8, 8, 8, 8), decoder="pca", components=3, pixels=5, map_size=32))
    vae.decoder.fit(maps, pixels)
    z = torch.randn(2, 4, 4, 4, generator=gen)
    with torch.no_grad():
        torch.testing.assert_close(vae.decode(z)[0].flatten(1)[:, pixels].flatten(), values.mean(0), atol=1e-5, rtol=0)
        vae.decoder.head.bias.copy_((values[7] - vae.decoder.mean) @ vae.decoder.basis.T)
        out = vae.decode(z)
    torch.testing.assert_close(out[1], maps[7], atol=1e-5, rtol=0)
    background = torch.ones(32 * 32, dtype=torch.bool)
    background[pixels] = False
    assert out.flatten(2)[:, :, background].abs().max() == 0
    assert vae.decoder_flops() == 2 * 3 * 15


def test_an_unknown_decoder_or_a_pca_head_without_pixels_is_refused():
    import pytest

    with pytest.raises(ValueError, match="unknown VAE decoder 'mlp'"):
        PositionVae(VaeConfig(decoder="mlp"))
    with pytest.raises(ValueError, match="foreground pixel count"):
        PositionVae(VaeConfig(decoder="pca"))
