"""Parity fixtures for the WGSL engine: for a tiny random-weight configuration, the inputs,
weights and outputs of every module kind (VAE encoder and decoder, each UNet block kind,
the timestep embedding, a whole UNet step, a DDIM step with CFG and a 4-step DDIM sample
from fixed noise (one file, `tiny_unet`), the PCA projection) as small safetensors files;
and one generated frame of the shipped Witch bundle (assets/witch/bundle) with its sampler defaults, so the engine is
pinned on real weights too.

    python -m unica_train.fixtures --out tests/fixtures/nn

Every file holds `io.in.*` inputs, `io.out.*` outputs and the module's weights under their
PyTorch state-dict names; the tiny configs are in tests/fixtures/nn/README.md."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from . import bundle, pca, splats
from . import checkpoint as checkpoint_file
from .diffusion import Schedule, ddim_step, guided_eps, sample_next, sampler_options
from .refiner import Refiner, RefinerConfig, features, from_bundle
from .refiner import apply as apply_residuals
from .layers import CrossAttention, Down, ResBlock, SpatialAttention, TemporalAttention, Up, timestep_embedding
from .unet import UNet, UNetConfig
from .vae import PositionVae, VaeConfig

WITCH_BUNDLE = Path(__file__).resolve().parents[2] / "assets" / "witch" / "bundle"
TINY_VAE = VaeConfig(channels=(16, 12, 8, 8))
# A PCA head over 300 foreground pixels of the 128² map, 24 components.
TINY_PCA_VAE = VaeConfig(channels=(16, 12, 8, 8), decoder="pca", components=24, pixels=300, map_size=128)
TINY_UNET = UNetConfig(channels=(16, 32), embed=32, heads=2)
# 300 points: 18 full patches of 16 and a tail of 12; 75 pooled points: 4 patches + 11.
TINY_REFINER = RefinerConfig(channels=[16, 32], depths=[1, 1], heads=[2, 2], decoder_depth=1, patch=16, stride=4)


def _randomise(module: torch.nn.Module, gen: torch.Generator) -> None:
    """Random weights everywhere (zero-initialised layers would test nothing)."""
    with torch.no_grad():
        for p in module.parameters():
            p.copy_(torch.randn(p.shape, generator=gen) * 0.2)


def build() -> dict[str, dict[str, torch.Tensor]]:
    gen = torch.Generator().manual_seed(1234)
    rand = lambda *shape: torch.randn(*shape, generator=gen)  # noqa: E731
    files: dict[str, dict[str, torch.Tensor]] = {}

    def module_file(name, module, inputs: dict, forward):
        _randomise(module, gen)
        with torch.no_grad():
            outputs = forward(module, **inputs)
        if not isinstance(outputs, dict):
            outputs = {"y": outputs}
        files[name] = {**{f"io.in.{k}": v for k, v in inputs.items()}, **{f"io.out.{k}": v for k, v in outputs.items()}, **module.state_dict()}

    module_file("resblock", ResBlock(8, 16, 32), {"x": rand(2, 8, 8, 8), "emb": rand(2, 32)}, lambda m, x, emb: m(x, emb))
    module_file("down", Down(8, 12), {"x": rand(1, 8, 16, 16)}, lambda m, x: m(x))
    module_file("up", Up(8, 12), {"x": rand(1, 8, 8, 8)}, lambda m, x: m(x))
    module_file("spatial_attention", SpatialAttention(16, 2), {"x": rand(2, 16, 8, 8)}, lambda m, x: m(x))
    module_file("cross_attention", CrossAttention(16, 32, 2), {"x": rand(2, 16, 8, 8), "ctx": rand(2, 1, 32)}, lambda m, x, ctx: m(x, ctx))
    module_file("temporal_attention", TemporalAttention(16, 4, 2), {"x": rand(8, 16, 4, 4)}, lambda m, x: m(x))
    files["timestep_embedding"] = {"io.in.t": torch.tensor([0.0, 1.0, 250.0, 999.0]), "io.out.y": timestep_embedding(torch.tensor([0.0, 1.0, 250.0, 999.0]), 32)}

    vae = PositionVae(TINY_VAE)
    module_file("vae_encoder", vae.encoder, {"x": rand(1, 3, 128, 128).clamp(0, 1)}, lambda m, x: dict(zip(("mean", "logvar"), m(x))))
    module_file("vae_decoder", vae.decoder, {"z": rand(1, 4, 16, 16)}, lambda m, z: m(z))

    unet = UNet(TINY_UNET)
    _randomise(unet, gen)
    x, t, action = rand(1, 4, 4, 16, 16), torch.tensor([[0, 0, 0, 700]]), torch.tensor([3])
    schedule = Schedule()
    with torch.no_grad():
        eps = unet(x, t, action)
        guided = guided_eps(unet, x, t, action, 2.0)
        stepped = ddim_step(schedule, x[:, -1], guided, 700, 600)
        noise = rand(1, 4, 16, 16)
        sample = sample_next(unet, schedule, x[:, :3], action, steps=4, cfg_scale=2.0, noise=noise)
    weights = unet.state_dict()
    # One file for the tiny UNet's three fixtures, so its weights are stored once: a
    # step's eps; a DDIM step with CFG (its guided eps and x_prev); a 4-step sample.
    files["tiny_unet"] = {"io.in.x": x, "io.in.t": t.float(), "io.in.action": action.float(), "io.out.eps": eps,
                          "io.in.cfg_scale": torch.tensor([2.0]), "io.in.t_prev": torch.tensor([600.0]),
                          "io.out.guided_eps": guided, "io.out.x_prev": stepped,
                          "io.in.context": x[:, :3].clone(), "io.in.noise": noise, "io.in.steps": torch.tensor([4.0]),
                          "io.out.x0": sample, **weights}
    data = rand(40, 30)
    mean, basis = pca.fit(data, 5)
    query = rand(3, 30)
    files["pca_projection"] = {"io.in.x": query, "io.in.mean": mean, "io.in.basis": basis, "io.out.y": pca.project(query, mean, basis)}
    files["alphas_cumprod"] = {"io.out.alphas_cumprod": schedule.alphas_cumprod}
    witch_noise = rand(1, 4, 16, 16)
    files["witch_frame"] = witch_frame(witch_noise)
    files["witch_idle_frame"] = witch_frame(witch_noise, action=0)
    files["witch_one_pass_frame"] = witch_frame(witch_noise, one_pass=True)
    files["witch_one_pass_idle_frame"] = witch_frame(witch_noise, action=0, one_pass=True)
    unit, feats = rand(300, 3).sigmoid(), rand(300, 11)
    module_file("refiner", Refiner(TINY_REFINER), {"features": feats, "unit": unit}, lambda m, features, unit: m(features, unit))
    files["base_splats"], files["witch_refiner"] = witch_splats()
    pixel_refiner = Refiner(RefinerConfig(**(TINY_REFINER.to_dict() | {"pixel_residuals": 300})))
    module_file("refiner_pixel", pixel_refiner, {"features": feats, "unit": unit}, lambda m, features, unit: m(features, unit))
    out = {name: {k: v.float().contiguous() for k, v in tensors.items()} for name, tensors in files.items()}
    out["vae_pca_decoder"] = pca_decoder()
    return out


def pca_decoder() -> dict[str, torch.Tensor]:
    """The tiny PCA-head decoder (its own generator, so the other fixtures do not move):
    random pixels, an orthonormal random basis, a random mean and head, two latents. The
    pixels stay int32, as in a bundle."""
    gen = torch.Generator().manual_seed(4321)
    decoder = PositionVae(TINY_PCA_VAE).decoder
    pixels = torch.randperm(128 * 128, generator=gen)[:TINY_PCA_VAE.pixels].sort().values
    q, _ = torch.linalg.qr(torch.randn(3 * TINY_PCA_VAE.pixels, TINY_PCA_VAE.components, generator=gen))
    with torch.no_grad():
        decoder.basis.copy_(q.T)
        decoder.mean.copy_(torch.rand(3 * TINY_PCA_VAE.pixels, generator=gen))
        decoder.pixels.copy_(pixels.int())
        _randomise(decoder, gen)
        z = torch.randn(2, 4, 16, 16, generator=gen)
        y = decoder(z)
    return {"io.in.z": z, "io.out.y": y, **{k: v.contiguous() for k, v in decoder.state_dict().items()}}


def witch_frame(noise: torch.Tensor, action: int = 1, one_pass: bool = False) -> dict[str, torch.Tensor]:
    """The Witch bundle's next latent after its standing-start context under `action`
    (Forward; Idle for Idle's own guidance scale), from `noise`, with the bundle's teacher
    sampler (DDIM steps, CFG scale, how Idle is guided, noise scale) or, `one_pass`, its
    distilled student's one pass; and the decoded position map."""
    vae, unet, extra, manifest = bundle.load(WITCH_BUNDLE)
    sampler, scale = manifest["sampler"], manifest["latent_scale"]
    model, steps, cfg = unet, sampler["ddim_steps"], sampler["cfg_scale"]
    if one_pass:
        model, steps, cfg = bundle.live_sampler(manifest, unet, extra)
        assert model is not unet, f"{WITCH_BUNDLE}: the shipped bundle has no one-pass student"
    action = torch.tensor([action])
    with torch.no_grad():
        z = sample_next(model, Schedule(), extra["context.latents"][None], action, steps, cfg, noise,
                        **sampler_options(sampler))
        decoded = vae.decode(z / scale)
    return {"io.in.noise": noise, "io.in.action": action.float(), "io.out.z": z, "io.out.map": decoded}


def witch_splats() -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
    """Base splats of the Witch bundle's mean PCA frame (a real map: six views, depth
    jumps) in normalised units, with the refiner's features; and the bundle's trained
    refiner on them, raw and applied."""
    _, _, extra, manifest = bundle.load(WITCH_BUNDLE)
    pixels = extra["map.pixels"].long()
    unit = extra["pca.mean"].reshape(-1, 3)
    nbrs = splats.neighbours(pixels, 128)
    base, normals = splats.base_splats(unit, extra["map.colors"], nbrs)
    median = splats.median_spacing(unit, nbrs)
    feats = features(unit, base, normals, median)
    base_file = {"io.in.unit": unit, "io.in.pixels": pixels.float(), "io.in.colors": extra["map.colors"], "io.out.scales": base.scales,
                 "io.out.rotations": base.rotations, "io.out.normals": normals, "io.out.median": median[None], "io.out.features": feats}
    model = from_bundle(manifest, extra)
    with torch.no_grad():
        raw = model(feats, unit)
        refined = apply_residuals(base, raw, model.cfg.mean_bound)
    refined_file = {"io.in.features": feats, "io.in.unit": unit, "io.out.y": raw, "io.out.means": refined.means,
                    "io.out.scales": refined.scales, "io.out.opacities": refined.opacities}
    return base_file, refined_file


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    built = build()
    for name, tensors in built.items():
        checkpoint_file.write_tensors(args.out / f"{name}.safetensors", tensors)
    print(f"wrote {len(built)} fixtures to {args.out}")


if __name__ == "__main__":
    main()
