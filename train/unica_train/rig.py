"""The auto-rigger's two models (specified in docs/autorig/models.md; src/autorig/model.rs
mirrors this file for CPU inference): the skeleton-token predictor (a point-cloud encoder
to M latents, then a causal transformer over [latents; tokens]) and the skin-weight model
(vertex and bone embeddings, a dot-product score plus geodesic and bone-distance priors,
softmax over bones). Every attention and MLP block is pre-LN with a residual.

Training on a rig-data directory (written by `unica rig-data`):

    python -m unica_train.rig --data DIR --out RUN --model skeleton|skin --steps N
        [--batch B] [--lr LR] [--resume] [--checkpoint-every N] [--init DIR] [--holdout K] [--threads 2] [--device cpu]
        [--arch JSON]

writes RUN/{model}.safetensors (f32 weights under the spec's names), {model}_config.json,
{model}_losses.csv, {model}_checkpoint.pt (every 200 steps or --checkpoint-every, for --resume) and
{model}_eval.json (the last K samples are held out). `--init DIR` starts from the weights
and architecture of DIR/{model}.safetensors and DIR/{model}_config.json (a fine-tune: new
optimiser, new schedule, its own losses). Parity fixtures for the Rust side:

    python -m unica_train.rig fixtures --out tests/fixtures/autorig
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from safetensors.torch import load_file
from torch import nn

from . import checkpoint as checkpoint_file
from .layers import attention
from .plot import curves

VOCAB = 265
BOS, EOS = 256, 257
FREQUENCIES = 6
FOURIER = 3 + 6 * FREQUENCIES  # 39
CHECKPOINT_EVERY = 200
EVAL_EVERY = 100


# ---------------------------------------------------------------------------- pieces


def fourier(x: torch.Tensor) -> torch.Tensor:
    """[..., 3] -> [..., 39]: x, then sin(2^k pi x) for k = 0..5 (three coordinates each),
    then cos likewise."""
    freqs = (2.0 ** torch.arange(FREQUENCIES, device=x.device)) * math.pi
    args = (x[..., None, :] * freqs[:, None]).flatten(-2)
    return torch.cat([x, args.sin(), args.cos()], -1)


def gelu(x: torch.Tensor) -> torch.Tensor:
    return F.gelu(x, approximate="tanh")


def embed_mlp(d_in: int, d: int) -> nn.Sequential:
    """Linear, GELU, Linear (state-dict names .0 and .2)."""
    return nn.Sequential(nn.Linear(d_in, d), nn.GELU(approximate="tanh"), nn.Linear(d, d))


def split_heads(x: torch.Tensor, heads: int) -> torch.Tensor:
    """[B, N, d] -> [B, heads, N, d/heads]."""
    b, n, d = x.shape
    return x.reshape(b, n, heads, d // heads).transpose(1, 2)


def attend(q, k, v, heads: int, allowed: torch.Tensor | None = None) -> torch.Tensor:
    """Multi-head attention of q [B, Nq, d] over k, v [B, Nk, d]; `allowed` is a bool mask
    [B or 1, Nq or 1, Nk]. Returns [B, Nq, d], heads concatenated."""
    b, n, d = q.shape
    mask = None if allowed is None else allowed[:, None]
    o = attention(split_heads(q, heads), split_heads(k, heads), split_heads(v, heads), mask)
    return o.transpose(1, 2).reshape(b, n, d)


class SelfAttention(nn.Module):
    def __init__(self, d: int, heads: int):
        super().__init__()
        self.heads = heads
        self.ln = nn.LayerNorm(d, eps=1e-5)
        self.qkv = nn.Linear(d, 3 * d)
        self.out = nn.Linear(d, d)

    def forward(self, x, allowed=None):
        q, k, v = self.qkv(self.ln(x)).chunk(3, -1)
        return x + self.out(attend(q, k, v, self.heads, allowed))


class CrossAttention(nn.Module):
    def __init__(self, d: int, heads: int):
        super().__init__()
        self.heads = heads
        self.ln_q = nn.LayerNorm(d, eps=1e-5)
        self.ln_kv = nn.LayerNorm(d, eps=1e-5)
        self.q = nn.Linear(d, d)
        self.kv = nn.Linear(d, 2 * d)
        self.out = nn.Linear(d, d)

    def forward(self, x, context):
        k, v = self.kv(self.ln_kv(context)).chunk(2, -1)
        return x + self.out(attend(self.q(self.ln_q(x)), k, v, self.heads))


class Mlp(nn.Module):
    def __init__(self, d: int):
        super().__init__()
        self.ln = nn.LayerNorm(d, eps=1e-5)
        self.fc1 = nn.Linear(d, 4 * d)
        self.fc2 = nn.Linear(4 * d, d)

    def forward(self, x):
        return x + self.fc2(gelu(self.fc1(self.ln(x))))


# ------------------------------------------------------------------ skeleton predictor


@dataclass
class SkeletonConfig:
    d: int = 128
    heads: int = 4
    latents: int = 32
    layers: int = 4
    max_len: int = 640


class Encoder(nn.Module):
    def __init__(self, cfg: SkeletonConfig):
        super().__init__()
        self.embed = embed_mlp(FOURIER + 3, cfg.d)
        self.latents = nn.Parameter(torch.randn(cfg.latents, cfg.d) * 0.02)
        self.cross = CrossAttention(cfg.d, cfg.heads)
        self.cross_mlp = Mlp(cfg.d)
        self.self = SelfAttention(cfg.d, cfg.heads)
        self.self_mlp = Mlp(cfg.d)

    def forward(self, points, normals):
        """points, normals [B, P, 3] -> latents [B, M, d]."""
        h = self.embed(torch.cat([fourier(points), normals], -1))
        x = self.latents.expand(points.shape[0], -1, -1)
        x = self.cross_mlp(self.cross(x, h))
        return self.self_mlp(self.self(x))


class Block(nn.Module):
    def __init__(self, d: int, heads: int):
        super().__init__()
        self.attn = SelfAttention(d, heads)
        self.mlp = Mlp(d)

    def forward(self, x, allowed):
        return self.mlp(self.attn(x, allowed))


class TokenDecoder(nn.Module):
    def __init__(self, cfg: SkeletonConfig):
        super().__init__()
        self.tok_emb = nn.Parameter(torch.randn(VOCAB, cfg.d) * 0.02)
        self.pos_emb = nn.Parameter(torch.randn(cfg.max_len, cfg.d) * 0.02)
        self.blocks = nn.ModuleList(Block(cfg.d, cfg.heads) for _ in range(cfg.layers))
        self.ln = nn.LayerNorm(cfg.d, eps=1e-5)
        self.head = nn.Linear(cfg.d, VOCAB)


def sequence_mask(latents: int, tokens: int, device=None) -> torch.Tensor:
    """[M+T, M+T] bool: latent rows see the latents; token row i sees the latents and
    tokens 0..i (row r sees column c iff c < M or c <= r)."""
    r = torch.arange(latents + tokens, device=device)
    return (r[None, :] < latents) | (r[None, :] <= r[:, None])


class SkeletonModel(nn.Module):
    def __init__(self, cfg: SkeletonConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = Encoder(cfg)
        self.decoder = TokenDecoder(cfg)

    def forward(self, points, normals, tokens):
        """tokens long [B, T] -> next-token logits [B, T, VOCAB]."""
        dec, m, t = self.decoder, self.cfg.latents, tokens.shape[1]
        x = torch.cat([self.encoder(points, normals), dec.tok_emb[tokens] + dec.pos_emb[:t]], 1)
        allowed = sequence_mask(m, t, x.device)[None]
        for block in dec.blocks:
            x = block(x, allowed)
        return dec.head(dec.ln(x[:, m:]))

    def loss(self, batch) -> torch.Tensor:
        """Teacher forcing: cross-entropy of tokens[1:] from the rows of tokens[:-1], over
        the real (unpadded) targets."""
        tokens, mask = batch["tokens"], batch["mask"]
        logits = self(batch["points"], batch["normals"], tokens[:, :-1])
        ce = F.cross_entropy(logits.transpose(1, 2), tokens[:, 1:], reduction="none")
        target = mask[:, 1:].float()
        return (ce * target).sum() / target.sum()


# ------------------------------------------------------------------------ skin model


@dataclass
class SkinConfig:
    d: int = 64
    heads: int = 4


def segment_distance(v, a, b) -> torch.Tensor:
    """Distance of each vertex v [B, V, 3] to each segment a-b ([B, J, 3]) -> [B, V, J];
    sqrt(|.|^2 + 1e-12) keeps the gradient finite on the segment."""
    ab = (b - a)[:, None]  # [B, 1, J, 3]
    av = v[:, :, None] - a[:, None]  # [B, V, J, 3]
    t = ((av * ab).sum(-1) / (ab * ab).sum(-1).clamp_min(1e-12)).clamp(0, 1)
    off = av - t[..., None] * ab
    return ((off * off).sum(-1) + 1e-12).sqrt()


class SkinNet(nn.Module):
    def __init__(self, cfg: SkinConfig):
        super().__init__()
        d = cfg.d
        self.vertex = embed_mlp(FOURIER + 3, d)
        self.context = nn.Linear(d, d)
        self.bone = embed_mlp(2 * FOURIER, d)
        self.bone_attn = SelfAttention(d, cfg.heads)
        self.bone_mlp = Mlp(d)
        self.ln_q = nn.LayerNorm(d, eps=1e-5)
        self.ln_k = nn.LayerNorm(d, eps=1e-5)
        self.q = nn.Linear(d, d)
        self.k = nn.Linear(d, d)
        self.prior_scale = nn.Parameter(torch.tensor([-20.0]))
        self.dist_scale = nn.Parameter(torch.tensor([0.0]))


class SkinModel(nn.Module):
    def __init__(self, cfg: SkinConfig):
        super().__init__()
        self.cfg = cfg
        self.skin = SkinNet(cfg)

    def forward(self, vertices, vertex_normals, joints, tails, geodesic, bones=None):
        """Logits [B, V, J] (-inf at padded bones; `bones` bool [B, J] marks the real ones)."""
        s = self.skin
        hv = s.vertex(torch.cat([fourier(vertices), vertex_normals], -1))
        hv = hv + s.context(hv.max(1, keepdim=True).values)
        hb = s.bone(torch.cat([fourier(joints), fourier(tails)], -1))
        hb = s.bone_mlp(s.bone_attn(hb, None if bones is None else bones[:, None, :]))
        score = s.q(s.ln_q(hv)) @ s.k(s.ln_k(hb)).transpose(1, 2) / math.sqrt(self.cfg.d)
        logits = score + s.prior_scale * geodesic + s.dist_scale * segment_distance(vertices, joints, tails)
        return logits if bones is None else logits.masked_fill(~bones[:, None, :], float("-inf"))

    def loss(self, batch) -> torch.Tensor:
        logits = self(batch["vertices"], batch["vertex_normals"], batch["joints"], batch["tails"], batch["geodesic"], batch["bones"])
        return skin_loss(logits, batch["skin"], batch["bones"])


def skin_loss(logits, target, bones) -> torch.Tensor:
    """-sum_b w_gt log p, mean over vertices (padded bones contribute nothing)."""
    logp = logits.log_softmax(-1).masked_fill(~bones[:, None, :], 0.0)
    return -(target * logp).sum(-1).mean()


def baseline_logits(geodesic, bones, beta: float) -> torch.Tensor:
    return (-beta * geodesic).masked_fill(~bones[:, None, :], float("-inf"))


def top4(weights: torch.Tensor) -> torch.Tensor:
    """Keeps the 4 largest weights per vertex, renormalised to sum 1 (same shape)."""
    k = min(4, weights.shape[-1])
    values, index = weights.topk(k, -1)
    kept = torch.zeros_like(weights).scatter(-1, index, values)
    return kept / kept.sum(-1, keepdim=True).clamp_min(1e-12)


# ----------------------------------------------------------------------------- data


class RigData:
    """A rig-data directory: manifest.json and sample_NNNNN.safetensors (read lazily)."""

    def __init__(self, root: Path):
        self.root = Path(root)
        self.manifest = json.loads((self.root / "manifest.json").read_text())
        if self.manifest.get("format") != "unica-rig-data":
            raise ValueError(f"{self.root}: not a unica-rig-data directory")
        if self.manifest.get("vocab", VOCAB) != VOCAB:
            raise ValueError(f"{self.root}: vocabulary {self.manifest['vocab']}, expected {VOCAB}")

    def __len__(self) -> int:
        return int(self.manifest["count"])

    def __getitem__(self, i: int) -> dict[str, torch.Tensor]:
        return load_file(str(self.root / f"sample_{i:05d}.safetensors"))


def pad_stack(tensors: list[torch.Tensor], value=0.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Pads the first axis to the longest and stacks: ([B, N, ...], valid bool [B, N])."""
    n = max(t.shape[0] for t in tensors)
    out = tensors[0].new_full((len(tensors), n, *tensors[0].shape[1:]), value)
    valid = torch.zeros(len(tensors), n, dtype=torch.bool)
    for i, t in enumerate(tensors):
        out[i, : t.shape[0]] = t
        valid[i, : t.shape[0]] = True
    return out, valid


def collate_skeleton(samples: list[dict]) -> dict[str, torch.Tensor]:
    """Token sequences padded with EOS; `mask` marks the real tokens."""
    tokens, mask = pad_stack([s["tokens"].long() for s in samples], EOS)
    return {"points": torch.stack([s["points"] for s in samples]), "normals": torch.stack([s["normals"] for s in samples]),
            "tokens": tokens, "mask": mask}


def collate_skin(samples: list[dict]) -> dict[str, torch.Tensor]:
    """Bones padded (zero geometry, zero weights); `bones` marks the real ones."""
    joints, bones = pad_stack([s["joints"] for s in samples])
    transposed = lambda key: pad_stack([s[key].T for s in samples])[0].transpose(1, 2)  # noqa: E731  [B, V, J]
    return {"vertices": torch.stack([s["vertices"] for s in samples]), "vertex_normals": torch.stack([s["vertex_normals"] for s in samples]),
            "joints": joints, "tails": pad_stack([s["bone_tails"] for s in samples])[0], "geodesic": transposed("geodesic"),
            "skin": transposed("skin"), "bones": bones}


COLLATE = {"skeleton": collate_skeleton, "skin": collate_skin}


def batches(data: RigData, indices: list[int], kind: str, size: int, device):
    for start in range(0, len(indices), size):
        batch = COLLATE[kind]([data[i] for i in indices[start : start + size]])
        yield {k: v.to(device) for k, v in batch.items()}


# ------------------------------------------------------------------ export, evaluation


def build(kind: str, arch: dict) -> nn.Module:
    return SkeletonModel(SkeletonConfig(**arch)) if kind == "skeleton" else SkinModel(SkinConfig(**arch))


def export(model: nn.Module, run: Path, kind: str, extra: dict, half: bool = False) -> None:
    """RUN/{kind}.safetensors (f32, or f16 with `half`: what ships, half the size, and
    `unica rig` writes the Witch's rig with the same stretches either way) and
    RUN/{kind}_config.json (architecture at the top level, where the Rust loader reads
    it, plus `extra`). Both loaders widen f16 to f32."""
    dtype = torch.float16 if half else torch.float32
    weights = {k: v.detach().to(dtype).cpu().contiguous() for k, v in model.state_dict().items()}
    # Written whole or not at all (the model `unica rig` loads), as checkpoints are.
    checkpoint_file.write_tensors(run / f"{kind}.safetensors", weights)
    config = json.dumps({"kind": kind, **asdict(model.cfg), **extra}, indent=2) + "\n"
    checkpoint_file.write_file_atomic(run / f"{kind}_config.json", config.encode())


def load(run: Path, kind: str) -> tuple[nn.Module, dict]:
    config = json.loads((run / f"{kind}_config.json").read_text())
    fields = SkeletonConfig.__dataclass_fields__ if kind == "skeleton" else SkinConfig.__dataclass_fields__
    model = build(kind, {k: config[k] for k in fields})
    model.load_state_dict(load_file(str(run / f"{kind}.safetensors")))
    return model, config


def fit_beta(data: RigData, indices: list[int], device, lo=0.1, hi=1000.0, iterations=40) -> float:
    """The beta of softmax(-beta * geodesic) minimising the skin loss on these samples: a
    golden-section search on log beta (the loss is convex in beta)."""
    loaded = list(batches(data, indices, "skin", 16, device))

    def loss(log_beta: float) -> float:
        with torch.no_grad():
            return sum(skin_loss(baseline_logits(b["geodesic"], b["bones"], math.exp(log_beta)), b["skin"], b["bones"]).item()
                       * len(b["skin"]) for b in loaded)

    a, b = math.log(lo), math.log(hi)
    g = (math.sqrt(5) - 1) / 2
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = loss(c), loss(d)
    for _ in range(iterations):
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = loss(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = loss(d)
    return math.exp((a + b) / 2)


def heldout_loss(model, data, indices, kind, batch, device) -> float:
    """The training loss over the held-out samples (batch means weighted by batch size)."""
    model.eval()
    with torch.no_grad():
        total = sum(model.loss(b).item() * len(b["normals" if kind == "skeleton" else "vertex_normals"])
                    for b in batches(data, indices, kind, batch, device))
    model.train()
    return total / len(indices)


def evaluate_skeleton(model, data, indices, batch, device) -> dict:
    """Held-out teacher-forced token cross-entropy and next-token accuracy (per token)."""
    model.eval()
    ce = correct = count = 0.0
    with torch.no_grad():
        for b in batches(data, indices, "skeleton", batch, device):
            logits = model(b["points"], b["normals"], b["tokens"][:, :-1])
            target, mask = b["tokens"][:, 1:], b["mask"][:, 1:]
            ce += (F.cross_entropy(logits.transpose(1, 2), target, reduction="none") * mask).sum().item()
            correct += ((logits.argmax(-1) == target) & mask).sum().item()
            count += mask.sum().item()
    model.train()
    return {"samples": len(indices), "tokens": int(count), "token_cross_entropy": ce / count, "next_token_accuracy": correct / count}


def evaluate_skin(model, data, indices, batch, device, beta: float) -> dict:
    """Held-out mean per-vertex L1 (sum over bones of |w - w_gt|) of the top-4
    renormalised weights, for the model and for the geodesic baseline."""
    model.eval()
    l1 = {"model": 0.0, "baseline": 0.0}
    vertices = 0
    with torch.no_grad():
        for b in batches(data, indices, "skin", batch, device):
            logits = {"model": model(b["vertices"], b["vertex_normals"], b["joints"], b["tails"], b["geodesic"], b["bones"]),
                      "baseline": baseline_logits(b["geodesic"], b["bones"], beta)}
            for name, x in logits.items():
                l1[name] += (top4(x.softmax(-1)) - b["skin"]).abs().sum().item()
            vertices += b["skin"].shape[0] * b["skin"].shape[1]
    model.train()
    return {"samples": len(indices), "baseline_beta": beta, "l1_model": l1["model"] / vertices, "l1_baseline": l1["baseline"] / vertices}


# ----------------------------------------------------------------------------- train


DEFAULTS = {"skeleton": {"batch": 8, "lr": 3e-4}, "skin": {"batch": 8, "lr": 1e-3}}


def learning_rate(step: int, steps: int, lr: float) -> float:
    """Linear warm-up over min(100, steps/10) steps, then cosine decay to 0."""
    warmup = max(1, min(100, steps // 10))
    if step < warmup:
        return lr * (step + 1) / warmup
    return lr * 0.5 * (1 + math.cos(math.pi * (step - warmup) / max(1, steps - warmup)))


def train(args) -> dict:
    torch.set_num_threads(args.threads)
    torch.manual_seed(args.seed)
    device = torch.device(args.device)
    kind, run = args.model, Path(args.out)
    run.mkdir(parents=True, exist_ok=True)
    data = RigData(args.data)
    holdout = min(args.holdout, len(data) - 1)
    train_idx, held_idx = list(range(len(data) - holdout)), list(range(len(data) - holdout, len(data)))
    batch = args.batch or DEFAULTS[kind]["batch"]
    lr = args.lr or DEFAULTS[kind]["lr"]
    extra = {}
    if args.init:
        if not (Path(args.init) / f"{kind}.safetensors").exists():
            raise SystemExit(f"error: {Path(args.init) / f'{kind}.safetensors'}: no such file (--init needs an exported {kind} model)")
        model, config = load(Path(args.init), kind)
        model = model.to(device)
        extra = {"init": {"from": str(args.init), "train": config.get("train")}}
        print(f"starting from {args.init}")
    else:
        model = build(kind, json.loads(args.arch)).to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=0.01)
    gen = torch.Generator().manual_seed(args.seed)
    checkpoint, losses = run / f"{kind}_checkpoint.pt", run / f"{kind}_losses.csv"
    start = 0
    if args.resume and checkpoint.exists():
        state = checkpoint_file.load(checkpoint, map_location=device)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        gen.set_state(state["gen"])
        start, extra = state["step"], state["extra"]
        print(f"resuming at step {start}")
    if args.resume and losses.exists():
        checkpoint_file.cut_log(losses, start)
    else:
        checkpoint_file.write_text(losses, "step,loss,heldout_loss\r\n")
    if kind == "skin" and "baseline_beta" not in extra:
        extra["baseline_beta"] = fit_beta(data, train_idx[:64], device)
        print(f"geodesic baseline beta {extra['baseline_beta']:.3f}")
    extra["train"] = {"data": str(args.data), "steps": args.steps, "batch": batch, "lr": lr, "weight_decay": 0.01, "clip": 1.0,
                      "holdout": holdout, "seed": args.seed, "samples": len(train_idx)}
    with losses.open("a", newline="") as f:
        out = csv.writer(f)
        began = time.time()
        for step in range(start, args.steps):
            for group in opt.param_groups:
                group["lr"] = learning_rate(step, args.steps, lr)
            pick = torch.randint(len(train_idx), (batch,), generator=gen).tolist()
            b = {k: v.to(device) for k, v in COLLATE[kind]([data[train_idx[i]] for i in pick]).items()}
            loss = model.loss(b)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
            opt.step()
            done = step + 1
            held = ""
            if held_idx and (done % EVAL_EVERY == 0 or done == args.steps):
                held = f"{heldout_loss(model, data, held_idx, kind, batch, device):.6f}"
            out.writerow([done, f"{loss.item():.6f}", held])
            f.flush()
            if done % 10 == 0 or done == args.steps or held:
                rate = (done - start) / (time.time() - began)
                print(f"{kind} step {done}/{args.steps} loss {loss.item():.4f}" + (f" held-out {held}" if held else "")
                      + f" ({rate:.2f} steps/s, {(args.steps - done) / rate / 60:.1f} min left)", flush=True)
            if done % (args.checkpoint_every or CHECKPOINT_EVERY) == 0 or done == args.steps:
                checkpoint_file.save({"model": model.state_dict(), "opt": opt.state_dict(), "gen": gen.get_state(), "step": done, "extra": extra}, checkpoint)
    export(model, run, kind, extra, half=True)
    write_curve(losses, run / f"{kind}_curve.png")
    result = {}
    if held_idx:
        if kind == "skeleton":
            result = evaluate_skeleton(model, data, held_idx, batch, device)
        else:
            result = evaluate_skin(model, data, held_idx, batch, device, extra["baseline_beta"])
        checkpoint_file.write_text(run / f"{kind}_eval.json", json.dumps(result, indent=2) + "\n")
        print(json.dumps(result, indent=2))
    return result


def write_curve(losses: Path, png: Path) -> None:
    """The training curve: training loss (mean of each 50 steps) and held-out loss."""
    rows = list(csv.DictReader(losses.open()))
    train = [(int(r["step"]), float(r["loss"])) for r in rows]
    smooth = [(train[i + 49][0], sum(v for _, v in train[i:i + 50]) / 50) for i in range(0, len(train) - 49, 50)]
    held = [(int(r["step"]), float(r["heldout_loss"])) for r in rows if r["heldout_loss"]]
    curves(png, {"training loss (50-step mean)": smooth, "held-out loss": held})


# -------------------------------------------------------------------------- fixtures


TINY_SKELETON = SkeletonConfig(d=24, heads=2, latents=4, layers=2, max_len=64)
TINY_SKIN = SkinConfig(d=16, heads=2)


def fixtures() -> dict[str, tuple[nn.Module | None, dict[str, torch.Tensor]]]:
    """Tiny models with random weights (N(0, 0.2^2), seed 1234; the skin priors set to
    prior_scale -5, dist_scale -3 so both terms matter) and their inputs and outputs:
    skeleton: 64 points, a 40-token prefix (BOS then random tokens) -> logits [40, VOCAB];
    skin: 50 vertices, 7 bones -> softmax weights [50, 7] and the baseline's for beta 3."""
    gen = torch.Generator().manual_seed(1234)
    rand = lambda *shape: torch.randn(*shape, generator=gen)  # noqa: E731
    unit = lambda *shape: torch.rand(*shape, generator=gen) * 2 - 1  # noqa: E731
    normal = lambda n: F.normalize(rand(n, 3), dim=-1)  # noqa: E731

    def randomise(model):
        with torch.no_grad():
            for p in model.parameters():
                p.copy_(torch.randn(p.shape, generator=gen) * 0.2)
        return model.eval()

    skeleton = randomise(SkeletonModel(TINY_SKELETON))
    points, normals = unit(64, 3), normal(64)
    tokens = torch.cat([torch.tensor([BOS]), torch.randint(VOCAB, (39,), generator=gen)])
    skin = randomise(SkinModel(TINY_SKIN))
    with torch.no_grad():
        skin.skin.prior_scale.fill_(-5.0)
        skin.skin.dist_scale.fill_(-3.0)
    vertices, vnormals, joints, tails = unit(50, 3), normal(50), unit(7, 3), unit(7, 3)
    geodesic = torch.rand(50, 7, generator=gen) * 2
    beta = torch.tensor([3.0])
    with torch.no_grad():
        logits = skeleton(points[None], normals[None], tokens[None])[0]
        weights = skin(vertices[None], vnormals[None], joints[None], tails[None], geodesic[None])[0].softmax(-1)
    return {
        "skeleton": (skeleton, {"points": points, "normals": normals, "tokens": tokens.int(), "logits": logits}),
        "skin": (skin, {"vertices": vertices, "vertex_normals": vnormals, "joints": joints, "bone_tails": tails, "geodesic": geodesic,
                        "weights": weights, "beta": beta, "baseline": (-beta * geodesic).softmax(-1)}),
    }


def write_fixtures(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for kind, (model, io) in fixtures().items():
        export(model, out, kind, {})
        checkpoint_file.write_tensors(out / f"{kind}_io.safetensors", io)
    print(f"wrote the skeleton and skin fixtures to {out}")


# ------------------------------------------------------------------------------- cli


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["fixtures"]:
        parser = argparse.ArgumentParser(prog="python -m unica_train.rig fixtures", description="Writes the Rust parity fixtures.")
        parser.add_argument("--out", type=Path, required=True)
        write_fixtures(parser.parse_args(argv[1:]).out)
        return None
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--model", choices=["skeleton", "skin"], required=True)
    parser.add_argument("--steps", type=int, required=True)
    parser.add_argument("--batch", type=int, help="default 8")
    parser.add_argument("--lr", type=float, help="default 3e-4 (skeleton), 1e-3 (skin)")
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--checkpoint-every", type=int, default=CHECKPOINT_EVERY, help=f"steps between checkpoints (default {CHECKPOINT_EVERY})")
    parser.add_argument("--init", type=Path, help="start from the exported model in this folder (e.g. assets/autorig)")
    parser.add_argument("--holdout", type=int, default=16, help="the last K samples are held out")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--arch", default="{}", help='architecture overrides as JSON, e.g. \'{"d": 64}\'')
    return train(parser.parse_args(argv))


if __name__ == "__main__":
    main()
