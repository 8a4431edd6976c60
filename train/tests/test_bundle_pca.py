"""PCA with known answers; bundle export -> import round trip and named load errors."""

import json

import pytest
import torch
from safetensors.torch import load_file, save_file

from unica_train import bundle, pca
from unica_train.unet import UNet, UNetConfig
from unica_train.vae import PositionVae, VaeConfig


def test_pca_recovers_a_low_dimensional_subspace():
    g = torch.Generator().manual_seed(0)
    basis = torch.linalg.qr(torch.randn(30, 3, generator=g))[0].T  # 3 orthonormal rows
    coeffs = torch.randn(200, 3, generator=g) * torch.tensor([5.0, 2.0, 1.0])
    frames = coeffs @ basis + 0.7
    mean, fitted = pca.fit(frames, 10)
    assert fitted.shape == (10, 30)
    top = fitted[:3]
    # The top 3 components span the same space; data in it projects onto itself.
    torch.testing.assert_close(pca.project(frames, mean, top), frames, atol=1e-4, rtol=0)
    off = frames[:1] + torch.randn(1, 30, generator=g)
    once = pca.project(off, mean, top)
    torch.testing.assert_close(pca.project(once, mean, top), once, atol=1e-5, rtol=0)
    assert torch.allclose(top @ top.T, torch.eye(3), atol=1e-5)


def small_models():
    torch.manual_seed(0)
    return PositionVae(VaeConfig(channels=(16, 12, 8, 8))), UNet(UNetConfig(channels=(16, 32), embed=32, heads=2))


def test_bundle_round_trip(tmp_path):
    vae, unet = small_models()
    extra = {"pca.mean": torch.rand(12), "pca.basis": torch.rand(2, 12), "map.pixels": torch.arange(4, dtype=torch.int32)}
    bundle.save(tmp_path, vae, unet, extra, {"avatar": "test", "actions": ["Idle"]})
    vae2, unet2, extra2, manifest = bundle.load(tmp_path)
    assert manifest["avatar"] == "test" and manifest["version"] == bundle.VERSION
    # The UNet's weight arrays and the PCA basis are stored as int8 with scales, its
    # vectors (biases, norms) and the VAE as float16, and read back widened; positions
    # (pca.mean) and integers stay exact.
    for a, b, int8 in [(vae, vae2, False), (unet, unet2, True)]:
        for (k, v), (k2, v2) in zip(a.state_dict().items(), b.state_dict().items()):
            assert k == k2 and v2.dtype == torch.float32
            want = bundle.dequantise(*bundle.quantise(v)) if int8 and v.dim() >= 2 else v.half().float()
            assert torch.equal(want, v2), k
            # Within half a step of the group's scale of the original.
            assert (v2 - v).abs().max() <= v.abs().max() / 254 + 2.0**-15 + 1e-7, k
    assert torch.equal(extra2["pca.basis"], bundle.dequantise(*bundle.quantise(extra["pca.basis"])))
    assert torch.equal(extra2["pca.mean"], extra["pca.mean"])
    assert torch.equal(extra2["map.pixels"], extra["map.pixels"])
    assert manifest["tensors"]["unet.conv_in.weight"] == {"shape": [16, 4, 3, 3], "dtype": "int8"}
    assert manifest["tensors"]["unet.conv_in.weight:scale"] == {"shape": [18], "dtype": "float16"}
    assert manifest["tensors"]["unet.conv_in.bias"]["dtype"] == "float16"
    assert manifest["tensors"]["pca.mean"]["dtype"] == "float32"
    raw = load_file(str(tmp_path / "weights.safetensors"))
    assert raw["vae.encoder.conv_in.weight"].dtype == torch.float16 and raw["pca.mean"].dtype == torch.float32
    # Reading and writing again stores the same bytes (the make rewrites bundles).
    again = tmp_path / "again"
    again.mkdir()
    bundle.write_weights(again, bundle.read_weights(tmp_path / "weights.safetensors"), manifest)
    assert (again / "weights.safetensors").read_bytes() == (tmp_path / "weights.safetensors").read_bytes()


def test_int8_storage_known_answers(tmp_path):
    # 33 values: a group of 32 whose largest magnitude is 2.54 (scale 0.02 as a half,
    # 0.0200043: 2.54 -> 127, 0.05 -> 2.4995 -> 2, -1.0 -> -50) and a group of one, 1e-3, under
    # 127 steps of 2^-14 (6.1e-5): it is stored as 16 of them.
    v = torch.zeros(33)
    v[0], v[1], v[2], v[32] = 2.54, 0.05, -1.0, 1e-3
    q, scale = bundle.quantise(v.reshape(3, 11))
    assert q.shape == (3, 11) and q.dtype == torch.int8 and scale.dtype == torch.float16
    assert scale.shape == (2,)
    assert abs(scale[0].item() - 0.02) < 1e-5 and scale[1].item() == 2.0**-14
    assert q.flatten()[:3].tolist() == [127, 2, -50] and q.flatten()[32].item() == 16
    back = bundle.dequantise(q, scale).flatten()
    assert abs(back[0].item() - 2.54) < 2e-3 and back[32].item() == 16 * 2.0**-14
    # A missing scale is named.
    save_file({"w": q}, str(tmp_path / "w.safetensors"))
    with pytest.raises(bundle.BundleError, match="'w:scale' is missing"):
        bundle.read_weights(tmp_path / "w.safetensors")


def test_a_student_is_stored_as_its_difference_from_the_unet(tmp_path):
    # The student (a UNet near the 10-step one) is stored as int8 of its difference from
    # the UNet as read back: read, it is within half a step of that difference's scale,
    # far finer than int8 of its own values; its vectors stay float16.
    _, unet = small_models()
    g = torch.Generator().manual_seed(3)
    tensors = {f"unet.{k}": v for k, v in unet.state_dict().items()}
    student = {f"student.{k}": v + 0.01 * v.abs().max() * torch.randn(v.shape, generator=g) for k, v in unet.state_dict().items()}
    tensors.update(student)
    bundle.write_weights(tmp_path, tensors, {})
    raw = load_file(str(tmp_path / "weights.safetensors"))
    read = bundle.read_weights(tmp_path / "weights.safetensors")
    name = "student.conv_in.weight"
    assert raw[name].dtype == torch.int8 and name + bundle.DELTA in raw and name + bundle.SCALE not in raw
    assert raw["student.conv_in.bias"].dtype == torch.float16
    diff = student[name] - read["unet.conv_in.weight"]
    assert (read[name] - student[name]).abs().max() <= diff.abs().max() / 254 + 2.0**-15 + 1e-7
    assert (read[name] - student[name]).abs().max() < (bundle.dequantise(*bundle.quantise(student[name])) - student[name]).abs().max() / 4
    # Reading and writing again stores the same bytes.
    again = tmp_path / "again"
    again.mkdir()
    bundle.write_weights(again, read, {})
    assert (again / "weights.safetensors").read_bytes() == (tmp_path / "weights.safetensors").read_bytes()
    # A difference without its base is named.
    save_file({name: raw[name], name + bundle.DELTA: raw[name + bundle.DELTA]}, str(tmp_path / "w.safetensors"))
    with pytest.raises(bundle.BundleError, match="'student.conv_in.weight' is stored as a difference but has no base"):
        bundle.read_weights(tmp_path / "w.safetensors")


def test_bundle_errors_name_the_tensor(tmp_path):
    vae, unet = small_models()
    bundle.save(tmp_path, vae, unet, {}, {})
    weights = load_file(str(tmp_path / "weights.safetensors"))
    weights["unet.conv_in.weight"] = torch.zeros(16, 4, 1, 1)
    save_file(weights, str(tmp_path / "weights.safetensors"))
    with pytest.raises(bundle.BundleError, match=r"'unet.conv_in.weight' is torch.float32 \[16, 4, 1, 1\], expected torch.float32 \[16, 4, 3, 3\]"):
        bundle.load(tmp_path)
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    manifest["version"] = 99
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(bundle.BundleError, match="bundle version 99"):
        bundle.load(tmp_path)


def test_pixel_colors_interpolate_the_vertex_colours(quick_dataset_dir):
    from unica_train.dataset import BakedDataset

    ds = BakedDataset(quick_dataset_dir)
    colors = ds.pixel_colors()
    assert colors.shape == (len(ds.pixels), 3)
    # Known answer for one pixel, by hand: Σ_k b_k · colour of the triangle's vertex k.
    i = len(ds.pixels) // 2
    tri = ds.triangles[ds.pixel_triangles[i]]
    expected = sum(ds.barycentrics[i, k] * ds.colors[tri[k]] for k in range(3))
    torch.testing.assert_close(colors[i], expected)
    assert colors.min() >= 0 and colors.max() <= 1


def test_add_colors_puts_the_pixel_colours_in_a_bundle(tmp_path, quick_dataset_dir):
    from unica_train.dataset import BakedDataset

    ds = BakedDataset(quick_dataset_dir)
    vae, unet = PositionVae(VaeConfig(channels=(8, 8, 8, 8))), UNet(UNetConfig(channels=(8, 8), embed=8, heads=2))
    bundle.save(tmp_path, vae, unet, {"map.pixels": ds.pixels.int()}, {})
    bundle.add_colors(tmp_path, quick_dataset_dir)
    tensors = load_file(str(tmp_path / "weights.safetensors"))
    torch.testing.assert_close(tensors["map.colors"], ds.pixel_colors())
    manifest = json.loads((tmp_path / "manifest.json").read_text())
    assert manifest["tensors"]["map.colors"]["shape"] == [len(ds.pixels), 3]
    bundle.load(tmp_path)  # still a valid bundle
    # Another character's pixels are refused.
    bundle.save(tmp_path, vae, unet, {"map.pixels": ds.pixels.int()[:-1]}, {})
    with pytest.raises(bundle.BundleError, match="not the bundle's"):
        bundle.add_colors(tmp_path, quick_dataset_dir)
