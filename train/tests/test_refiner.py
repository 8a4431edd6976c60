"""The refiner: serialisation with known answers, patch attention, identity at start,
and a bundle round trip."""

import itertools

import torch

from unica_train import refiner as R
from unica_train import splats as S


def test_z_order_interleaves_x_then_y_then_z():
    cells = torch.tensor([[1, 0, 0], [0, 1, 0], [0, 0, 1], [2, 0, 0], [1023, 1023, 1023]])
    assert R.z_order(cells).tolist() == [4, 2, 1, 32, (1 << 30) - 1]


def test_the_hilbert_curve_walks_its_first_block_cell_by_cell():
    cells = torch.tensor(list(itertools.product(range(4), repeat=3)))
    code = R.hilbert(cells)
    order = torch.argsort(code)
    assert code[order].tolist() == list(range(64))
    steps = (cells[order][1:] - cells[order][:-1]).abs().sum(1)
    assert (steps == 1).all()


def test_transposed_orders_swap_x_and_y():
    unit = torch.tensor([[0.9, 0.1, 0.1], [0.1, 0.1, 0.1], [0.1, 0.1, 0.1], [0.1, 0.9, 0.1]])
    assert R.serialise(unit, "z").tolist() == [1, 2, 3, 0]
    assert R.serialise(unit, "z-trans").tolist() == [1, 2, 0, 3]


def test_patch_attention_with_one_patch_is_plain_attention():
    gen = torch.Generator().manual_seed(0)
    qkv = torch.randn(10, 3 * 8, generator=gen)
    order = torch.randperm(10, generator=gen)
    got = R.patch_attention(qkv, order, 16, 2)
    q, k, v = qkv.reshape(10, 3, 2, 4).permute(1, 2, 0, 3)
    want = torch.softmax(q @ k.transpose(1, 2) / 2.0, -1) @ v  # [2, 10, 4]
    assert torch.allclose(got, want.transpose(0, 1).reshape(10, 8), atol=1e-6)
    # Patches of 4 along the order: a point only sees its own patch.
    part = R.patch_attention(qkv, order, 4, 2)
    first = order[:4]
    alone = R.patch_attention(qkv[first], torch.arange(4), 4, 2)
    assert torch.allclose(part[first], alone, atol=1e-6)


def test_pooling_averages_runs_along_the_order():
    x = torch.tensor([[1.0], [2.0], [3.0], [4.0], [5.0]])
    order = torch.tensor([4, 0, 1, 2, 3])
    assert R.segment_mean(x, order, 2).flatten().tolist() == [3.0, 2.5, 4.0]
    group, count = R.pool_groups(order, 2)
    assert group.tolist() == [0, 1, 1, 2, 0] and count == 3


def test_a_new_refiner_is_the_identity_and_can_learn():
    gen = torch.Generator().manual_seed(0)
    unit = torch.rand(200, 3, generator=gen)
    feats = torch.randn(200, R.FEATURES, generator=gen)
    model = R.Refiner(R.RefinerConfig(patch=16))
    raw = model(feats, unit)
    assert torch.equal(raw, torch.zeros_like(raw))
    base = S.Splats(unit, torch.rand(200, 3, generator=gen), torch.full((200, 3), 0.01),
                    torch.tensor([[0.0, 0, 0, 1]]).expand(200, 4), torch.full((200,), S.OPACITY))
    same = R.apply(base, raw, 0.01)
    for f in ("means", "colors", "scales", "rotations"):
        assert torch.allclose(getattr(same, f), getattr(base, f))
    assert torch.allclose(same.opacities, base.opacities)
    raw.sum().backward()
    assert model.head.weight.grad.abs().sum() > 0


def test_flops_count_the_linear_layers_and_attention():
    cfg = R.RefinerConfig(channels=[8, 16], depths=[1, 0], heads=[1, 1], decoder_depth=0, patch=4, stride=2)
    # embed 2·N·11·8, one block at 8 channels, down 2·(N/2)·8·16, up 2·(N/2)·16·8, head 2·N·8·14.
    n = 10
    block = 2 * n * 8 * 8 * 8 + 4 * n * 4 * 8
    want = 2 * n * 11 * 8 + block + 2 * 5 * 8 * 16 + 2 * 5 * 16 * 8 + 2 * n * 8 * 14
    assert R.flops(cfg, n) == want


def test_a_refiner_starts_from_another_bundles_refiner_with_the_same_config(tmp_path):
    import json

    import pytest
    from safetensors.torch import save_file

    from unica_train import bundle as B

    save_file({"pca.mean": torch.zeros(3)}, str(tmp_path / "weights.safetensors"))
    (tmp_path / "manifest.json").write_text(json.dumps({"avatar": "test"}))
    cfg = R.RefinerConfig(patch=16)
    trained = R.Refiner(cfg)
    with torch.no_grad():
        for p in trained.parameters():
            p.add_(torch.randn_like(p))
    R.add_to_bundle(tmp_path, trained)
    started = R.Refiner(cfg)
    R.init_from_bundle(started, tmp_path)
    # A bundle stores the refiner as float16 (bundle.HALF): it starts from the halves.
    for (name, a), (_, b) in zip(trained.state_dict().items(), started.state_dict().items()):
        assert torch.equal(a.half().float(), b), name
    with pytest.raises(B.BundleError, match="refiner config"):
        R.init_from_bundle(R.Refiner(R.RefinerConfig(patch=32)), tmp_path)


def test_per_pixel_residuals_add_each_points_own_row_and_start_at_zero_from_a_bundle(tmp_path):
    import json

    import pytest
    from safetensors.torch import save_file

    from unica_train import bundle as B

    gen = torch.Generator().manual_seed(1)
    unit = torch.rand(40, 3, generator=gen)
    feats = torch.randn(40, R.FEATURES, generator=gen)
    plain = R.Refiner(R.RefinerConfig(patch=16))
    with torch.no_grad():
        for p in plain.parameters():
            p.add_(0.1 * torch.randn(p.shape, generator=gen))
    table = R.Refiner(R.RefinerConfig(patch=16, pixel_residuals=40))
    table.load_state_dict(plain.state_dict() | {"pixel": torch.arange(40 * R.OUTPUTS, dtype=torch.float32).reshape(40, R.OUTPUTS)})
    with torch.no_grad():
        # Row i of the table is added to point i's residuals, nothing else changes.
        assert torch.allclose(table(feats, unit) - plain(feats, unit), table.pixel, atol=1e-4)
        with pytest.raises(ValueError, match="40 rows for 39 points"):
            table(feats[:39], unit[:39])
    # The flops count its add.
    assert R.flops(table.cfg, 40) == R.flops(plain.cfg, 40) + 40 * R.OUTPUTS
    # Started from a bundle without a table, the network is the bundle's and the table zero.
    save_file({"pca.mean": torch.zeros(3)}, str(tmp_path / "weights.safetensors"))
    (tmp_path / "manifest.json").write_text(json.dumps({"avatar": "test"}))
    R.add_to_bundle(tmp_path, plain)
    started = R.Refiner(R.RefinerConfig(patch=16, pixel_residuals=40))
    R.init_from_bundle(started, tmp_path)
    assert torch.equal(started.pixel, torch.zeros(40, R.OUTPUTS))
    # The bundle holds the network as float16 (bundle.HALF): the network's halves.
    halved = R.Refiner(R.RefinerConfig(patch=16))
    halved.load_state_dict({k: v.half().float() for k, v in plain.state_dict().items()})
    with torch.no_grad():
        assert torch.allclose(started(feats, unit), halved(feats, unit))
    # A bundle with a table of another size is refused.
    R.add_to_bundle(tmp_path, table)
    with pytest.raises(B.BundleError, match="refiner config"):
        R.init_from_bundle(R.Refiner(R.RefinerConfig(patch=16, pixel_residuals=41)), tmp_path)
    again = R.Refiner(R.RefinerConfig(patch=16, pixel_residuals=40))
    R.init_from_bundle(again, tmp_path)
    assert torch.equal(again.pixel, table.pixel)


def test_held_out_frames_are_spread_over_the_held_out_clips_and_none_is_an_error():
    from types import SimpleNamespace

    import pytest

    frames = SimpleNamespace(keys=[(c, f) for c in range(3) for f in range(10)], dir="data/renders")
    cfg = R.RefinerTrainConfig(held_out_clips=[1], eval_frames=5)
    assert R.held_out_keys(frames, cfg) == [(1, 0), (1, 2), (1, 4), (1, 6), (1, 8)]
    with pytest.raises(ValueError, match=r"data/renders: no rendered frame of the held-out clips \[7\]"):
        R.held_out_keys(frames, R.RefinerTrainConfig(held_out_clips=[7]))


def test_generated_inputs_are_the_bundles_teacher_forced_next_frames(quick_dataset_dir, tmp_path):
    import json
    from pathlib import Path

    import pytest

    from unica_train.dataset import BakedDataset

    config = tmp_path / "refiner.json"
    config.write_text(json.dumps({"generated_fraction": 1.5}))
    with pytest.raises(ValueError, match=r"refiner.json: generated_fraction 1.5 is not in \[0, 1\]"):
        R.train_config(config)
    bundle = Path(__file__).resolve().parents[2] / "assets" / "witch" / "bundle"
    assert R.frame_generator(bundle, quick_dataset_dir, R.RefinerTrainConfig()) is None
    generate = R.frame_generator(bundle, quick_dataset_dir, R.RefinerTrainConfig(generated_fraction=0.5))
    ds = BakedDataset(quick_dataset_dir)
    clip = next(c for c, meta in enumerate(ds.clips) if len(meta["actions"]) > 12 and bool(meta["actions"][:12].all()))
    a = generate(clip, 10, torch.Generator().manual_seed(0))  # a walking frame
    b = generate(clip, 10, torch.Generator().manual_seed(0))
    c = generate(clip, 10, torch.Generator().manual_seed(1))
    assert torch.equal(a, b) and not torch.equal(a, c)  # fresh noise per call, reproducible per seed
    # The generated frame is the next frame: about a centimetre from the truth (mean point
    # distance, world space), and further from every other frame around it.
    truth = ds.positions(clip, [8, 9, 10, 11, 12])
    error = [(a - t).norm(dim=1).mean().item() for t in truth]
    assert 0 < error[2] < 0.02 and error[2] == min(error), error
