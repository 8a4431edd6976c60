"""The auto-rig models (unica_train.rig) on synthetic random rig-data directories: shapes,
masks, the dataset reader's padding, training, export, fixtures."""

import argparse
import csv
import json
import math

import pytest
import torch
from safetensors.torch import load_file, save_file

from conftest import FIXTURES
from unica_train import rig

TINY_SKELETON = {"d": 32, "heads": 2, "latents": 4, "layers": 2, "max_len": 64}
TINY_SKIN = {"d": 16, "heads": 2}


def write_dataset(root, count=6, points=32, vertices=20, beta=4.0, seed=0):
    """Random samples in the rig-data format: tokens BOS ... EOS of varying length, 3-6
    bones, skin weights softmax(-beta * geodesic)."""
    gen = torch.Generator().manual_seed(seed)
    root.mkdir(parents=True, exist_ok=True)
    manifest = {"format": "unica-rig-data", "version": 1, "count": count, "points": points, "vertices": vertices, "vocab": 265, "seed": seed}
    (root / "manifest.json").write_text(json.dumps(manifest))
    for i in range(count):
        t, j = 8 + 3 * i, 3 + i % 4
        body = torch.randint(256, (t - 2,), generator=gen)
        geodesic = torch.rand(vertices, j, generator=gen) * 2
        sample = {
            "points": torch.rand(points, 3, generator=gen) * 2 - 1,
            "normals": torch.nn.functional.normalize(torch.randn(points, 3, generator=gen), dim=-1),
            "tokens": torch.cat([torch.tensor([rig.BOS]), body, torch.tensor([rig.EOS])]).int(),
            "joints": torch.rand(j, 3, generator=gen) * 2 - 1,
            "parents": torch.arange(-1, j - 1).int(),
            "bone_tails": torch.rand(j, 3, generator=gen) * 2 - 1,
            "vertices": torch.rand(vertices, 3, generator=gen) * 2 - 1,
            "vertex_normals": torch.nn.functional.normalize(torch.randn(vertices, 3, generator=gen), dim=-1),
            "skin": (-beta * geodesic).softmax(-1),
            "geodesic": geodesic,
        }
        save_file(sample, str(root / f"sample_{i:05d}.safetensors"))
    return rig.RigData(root)


@pytest.fixture
def data(tmp_path):
    return write_dataset(tmp_path / "data")


def skeleton_model(seed=0):
    torch.manual_seed(seed)
    return rig.SkeletonModel(rig.SkeletonConfig(**TINY_SKELETON)).eval()


def skin_model(seed=0):
    torch.manual_seed(seed)
    model = rig.SkinModel(rig.SkinConfig(**TINY_SKIN)).eval()
    with torch.no_grad():
        model.skin.dist_scale.fill_(-2.0)
    return model


def test_fourier_features_have_the_documented_order():
    x = torch.tensor([0.5, 0.25, 0.0])
    f = rig.fourier(x)
    assert f.shape == (39,)
    s = math.sqrt(0.5)
    torch.testing.assert_close(f[:3], x)
    torch.testing.assert_close(f[3:6], torch.tensor([1.0, s, 0.0]))  # sin(pi x)
    torch.testing.assert_close(f[6:9], torch.tensor([0.0, 1.0, 0.0]), atol=1e-6, rtol=0)  # sin(2 pi x)
    torch.testing.assert_close(f[21:24], torch.tensor([0.0, s, 1.0]), atol=1e-6, rtol=0)  # cos(pi x)
    torch.testing.assert_close(f[36:39], torch.tensor([1.0, 1.0, 1.0]))  # cos(32 pi x)


def test_shapes_and_padding(data):
    sk = rig.collate_skeleton([data[0], data[3]])
    assert sk["tokens"].shape == (2, 17) and sk["points"].shape == (2, 32, 3)
    assert (sk["tokens"][0, 8:] == rig.EOS).all() and sk["mask"].sum(1).tolist() == [8, 17]
    logits = skeleton_model()(sk["points"], sk["normals"], sk["tokens"])
    assert logits.shape == (2, 17, rig.VOCAB)
    sn = rig.collate_skin([data[0], data[3]])
    assert sn["joints"].shape == (2, 6, 3) and sn["geodesic"].shape == (2, 20, 6) and sn["skin"].shape == (2, 20, 6)
    assert sn["bones"].sum(1).tolist() == [3, 6]
    torch.testing.assert_close(sn["geodesic"][0, :, :3], data[0]["geodesic"])
    w = skin_model()(sn["vertices"], sn["vertex_normals"], sn["joints"], sn["tails"], sn["geodesic"], sn["bones"]).softmax(-1)
    assert w.shape == (2, 20, 6)
    torch.testing.assert_close(w.sum(-1), torch.ones(2, 20))


def test_the_decoder_is_causal(data):
    model = skeleton_model()
    s = data[4]
    tokens = s["tokens"].long()[None]
    changed = tokens.clone()
    changed[0, 10:] = (changed[0, 10:] + 7) % rig.VOCAB
    with torch.no_grad():
        a = model(s["points"][None], s["normals"][None], tokens)
        b = model(s["points"][None], s["normals"][None], changed)
    torch.testing.assert_close(a[:, :10], b[:, :10])
    assert (a[:, 10:] - b[:, 10:]).abs().max() > 1e-3


def test_latent_rows_do_not_see_tokens(data):
    model = skeleton_model()
    m = TINY_SKELETON["latents"]
    assert not rig.sequence_mask(m, 5)[:m, m:].any()
    rows = []
    model.decoder.blocks[-1].register_forward_hook(lambda mod, inputs, out: rows.append(out[:, :m]))
    s = data[2]
    with torch.no_grad():
        model(s["points"][None], s["normals"][None], s["tokens"].long()[None])
        model(s["points"][None], s["normals"][None], torch.randint(rig.VOCAB, (1, 9)))
    torch.testing.assert_close(rows[0], rows[1])


def test_padded_bones_change_nothing(data):
    model = skin_model()
    alone = rig.collate_skin([data[0]])
    padded = rig.collate_skin([data[0], data[3]])
    # Garbage in the padding: it must neither receive weight nor change the real bones'.
    padded["joints"][0, 3:] = 5.0
    padded["geodesic"][0, :, 3:] = -100.0
    keys = ["vertices", "vertex_normals", "joints", "tails", "geodesic", "bones"]
    with torch.no_grad():
        w1 = model(*(alone[k] for k in keys)).softmax(-1)
        w2 = model(*(padded[k] for k in keys)).softmax(-1)
    torch.testing.assert_close(w2[0, :, :3], w1[0])
    assert (w2[0, :, 3:] == 0).all()
    assert torch.isfinite(rig.skin_loss(model(*(padded[k] for k in keys)), padded["skin"], padded["bones"]))


def test_top4_keeps_the_largest_renormalised():
    w = torch.tensor([[0.05, 0.3, 0.1, 0.25, 0.2, 0.09]])
    torch.testing.assert_close(top := rig.top4(w), torch.tensor([[0.0, 0.3, 0.1, 0.25, 0.2, 0.0]]) / 0.85)
    assert (top > 0).sum() == 4


def test_baseline_beta_is_recovered(data):
    beta = rig.fit_beta(data, list(range(len(data))), "cpu")
    assert abs(beta - 4.0) < 0.01, beta


def args(data, out, model, steps, **extra):
    base = {"data": data.root, "out": out, "model": model, "steps": steps, "batch": 4, "lr": 3e-3, "resume": False,
            "holdout": 2, "threads": 2, "device": "cpu", "seed": 0, "init": None, "checkpoint_every": None,
            "arch": json.dumps(TINY_SKELETON if model == "skeleton" else TINY_SKIN)}
    return argparse.Namespace(**{**base, **extra})


def losses(path):
    rows = list(csv.DictReader(path.open()))
    return [float(r["loss"]) for r in rows], rows


@pytest.mark.parametrize("kind", ["skeleton", "skin"])
def test_training_overfits_and_writes_its_outputs(data, tmp_path, kind, monkeypatch):
    monkeypatch.setattr(rig, "EVAL_EVERY", 50)
    monkeypatch.setattr(rig, "CHECKPOINT_EVERY", 40)
    run = tmp_path / "run"
    result = rig.train(args(data, run, kind, 80))
    values, rows = losses(run / f"{kind}_losses.csv")
    assert len(values) == 80 and rows[49]["heldout_loss"] and rows[79]["heldout_loss"] and not rows[50]["heldout_loss"]
    assert sum(values[-10:]) / 10 < 0.7 * sum(values[:10]) / 10, (values[:10], values[-10:])
    for name in [f"{kind}.safetensors", f"{kind}_config.json", f"{kind}_checkpoint.pt", f"{kind}_eval.json"]:
        assert (run / name).exists(), name
    assert json.loads((run / f"{kind}_eval.json").read_text()) == result
    if kind == "skin":
        assert abs(result["baseline_beta"] - 4.0) < 0.05
        assert result["l1_baseline"] < 0.5 and 0 <= result["l1_model"] <= 2
    else:
        assert result["tokens"] == 19 + 22 and 0 <= result["next_token_accuracy"] <= 1
    # A 50-step run (checkpointed at 40 and at its end) goes on to 60 with --resume,
    # continuing its losses file.
    rig.train(args(data, run, kind, 50))
    rig.train(args(data, run, kind, 60, resume=True))
    steps = [int(r["step"]) for r in losses(run / f"{kind}_losses.csv")[1]]
    assert steps == list(range(1, 61))


def test_init_starts_from_an_exported_model(data, tmp_path, monkeypatch):
    """--init DIR: the run's first step starts from DIR's weights (its held-out loss at
    step 0 is the exported model's), records where it came from, and refuses a folder
    without the model."""
    monkeypatch.setattr(rig, "EVAL_EVERY", 1000)
    first = tmp_path / "first"
    rig.train(args(data, first, "skeleton", 60))
    exported, _ = rig.load(first, "skeleton")
    samples = rig.RigData(data.root)
    idx = [len(samples) - 2, len(samples) - 1]
    before = rig.heldout_loss(exported, samples, idx, "skeleton", 4, torch.device("cpu"))
    fresh_loss = rig.heldout_loss(rig.build("skeleton", TINY_SKELETON), samples, idx, "skeleton", 4, torch.device("cpu"))
    second = tmp_path / "second"
    # A vanishing learning rate: the fine-tune must leave the weights as it found them
    # (a run that ignored --init would start from fresh random weights).
    rig.train(args(data, second, "skeleton", 2, init=first, lr=1e-12))
    continued, config = rig.load(second, "skeleton")
    for (name, a), (_, b) in zip(exported.state_dict().items(), continued.state_dict().items()):
        assert torch.allclose(a, b), name
    assert config["init"]["from"] == str(first) and config["init"]["train"]["steps"] == 60
    after = rig.heldout_loss(continued, samples, idx, "skeleton", 4, torch.device("cpu"))
    assert abs(after - before) < 1e-5 and abs(fresh_loss - before) > 1e-3
    with pytest.raises(SystemExit, match="skin.safetensors"):
        rig.train(args(data, tmp_path / "third", "skin", 2, init=first))


def test_export_import_round_trip(tmp_path):
    model = skin_model(3)
    rig.export(model, tmp_path, "skin", {"baseline_beta": 2.5})
    loaded, config = rig.load(tmp_path, "skin")
    assert config["baseline_beta"] == 2.5 and config["d"] == 16
    for (name, a), (name_b, b) in zip(model.state_dict().items(), loaded.state_dict().items()):
        assert name == name_b and torch.equal(a, b)
    model = skeleton_model(4)
    rig.export(model, tmp_path, "skeleton", {})
    keys = set(load_file(str(tmp_path / "skeleton.safetensors")))
    assert {"encoder.embed.0.weight", "encoder.latents", "encoder.cross.kv.weight", "encoder.self.qkv.bias", "decoder.tok_emb",
            "decoder.pos_emb", "decoder.blocks.1.mlp.fc2.weight", "decoder.head.bias"} <= keys
    assert rig.load(tmp_path, "skeleton")[0].decoder.tok_emb.equal(model.decoder.tok_emb)
    # As shipped: float16, read back widened to float32.
    rig.export(model, tmp_path, "skeleton", {}, half=True)
    assert load_file(str(tmp_path / "skeleton.safetensors"))["decoder.tok_emb"].dtype == torch.float16
    loaded = rig.load(tmp_path, "skeleton")[0].decoder.tok_emb
    assert loaded.dtype == torch.float32 and loaded.equal(model.decoder.tok_emb.half().float())


def test_committed_autorig_fixtures_are_current():
    """tests/fixtures/autorig is what `python -m unica_train.rig fixtures` writes now."""
    folder = FIXTURES / "autorig"
    for kind, (model, io) in rig.fixtures().items():
        for name, tensors in [(kind, model.state_dict()), (f"{kind}_io", io)]:
            path = folder / f"{name}.safetensors"
            assert path.stat().st_size < 200_000, path
            saved = load_file(str(path))
            assert sorted(saved) == sorted(tensors), name
            for key, value in tensors.items():
                torch.testing.assert_close(saved[key], value, atol=1e-5, rtol=1e-5, msg=f"{name}:{key}")
