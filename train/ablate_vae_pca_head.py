"""Issue #17 ablation: the shipped conv VAE decoder against a linear PCA-head decoder (map
foreground = mean + (W z) @ basis, the basis fitted on training maps), with the same
encoder, data, seed, steps and loop as Run.train_vae. Prints the train-batch L1 in mm (as
the earlier decoder ablation) and the held-out reconstruction in mm (as Run.evaluate: mean
point distance over every 7th held-out group).

    python3 train/ablate_vae_pca_head.py DATA STEPS COMPONENTS conv pca
"""
import math, sys, time
from pathlib import Path
import torch, torch.nn as nn
from unica_train import pca
from unica_train.train import Run, TrainConfig
from unica_train.vae import PositionVae, VaeConfig

data, steps, components = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3])
arms = sys.argv[4:]

class PcaHead(nn.Module):
    def __init__(self, latent_dim, mean, basis, fg):
        super().__init__()
        self.register_buffer("mean", mean)
        self.register_buffer("basis", basis)
        self.register_buffer("fg", fg)
        self.linear = nn.Linear(latent_dim, basis.shape[0])
        nn.init.zeros_(self.linear.weight); nn.init.zeros_(self.linear.bias)

    def forward(self, z):
        values = self.mean + self.linear(z.flatten(1)) @ self.basis  # [N, 3P]
        out = torch.zeros(z.shape[0], 3, 128 * 128, device=z.device)
        out[:, :, self.fg] = values.view(z.shape[0], 3, -1)
        return out.view(z.shape[0], 3, 128, 128)

for arm in arms:
    cfg = TrainConfig(); cfg.vae_steps = steps; cfg.checkpoint_every = 10**9
    out = Path(f"/tmp/ablate_{arm}_{steps}"); (out / "checkpoints").mkdir(parents=True, exist_ok=True)
    torch.manual_seed(0)
    run = Run(data, out, cfg, torch.device("cpu"))
    vae = PositionVae(VaeConfig())
    fg = run.ds.pixels
    if arm == "pca":
        t0 = time.time()
        picks = torch.randperm(len(run.train_groups), generator=torch.Generator().manual_seed(1))[:600]
        maps = torch.cat([run.group_maps(run.train_groups[i]) for i in picks])  # [2400, 3, 128, 128]
        flat = maps.flatten(2)[:, :, fg].flatten(1)
        mean, basis = pca.fit(flat, components)
        held = torch.cat([run.group_maps(i) for i in run.test_groups[::7]])
        hf = held.flatten(2)[:, :, fg].flatten(1)
        rec = pca.project(hf, mean, basis)
        mm = (rec - hf).view(hf.shape[0], 3, -1).norm(dim=1).mean().item() / run.ds.scale * 1000
        print(f"pca of {flat.shape[0]} training maps, {components} components: held-out {mm:.2f} mm ({time.time()-t0:.0f} s)", flush=True)
        vae.decoder = PcaHead(VaeConfig().latent * 256, mean, basis, fg)
    opt = torch.optim.AdamW(vae.parameters(), lr=cfg.vae_lr)
    start, step, last = time.time(), 0, []
    while step < steps:
        x = torch.cat([run.group_maps(i)[torch.randint(4, (1,), generator=run.gen)] for i in run.pick(run.train_groups, cfg.vae_batch)])
        for g in opt.param_groups:
            g["lr"] = cfg.vae_lr * 0.5 * (1 + math.cos(math.pi * step / steps))
        loss, parts = vae(x, run.mask)
        opt.zero_grad(); loss.backward(); opt.step(); step += 1
        if step % 50 == 0:
            last.append(parts["l1"] / run.ds.scale * 1000)
            print(f"{arm} step {step} l1 {last[-1]:.1f} mm {time.time()-start:.0f} s", flush=True)
    with torch.no_grad():
        vae.eval()
        errs = []
        for i in run.test_groups[::7]:
            m = run.group_maps(i)
            r = vae.decode(vae.encoder(m)[0])
            errs.append((r - m).flatten(2)[:, :, fg].norm(dim=1).mean().item() / run.ds.scale * 1000)
    print(f"decoder {arm}: steps {steps} train l1 mm mean of last 4 {sum(last[-4:])/4:.1f}; held-out {sum(errs)/len(errs):.1f} mm; {time.time()-start:.0f} s", flush=True)
