"""The Python dataset reader against the Rust one: same positions (LBS + gather), same
group normalisation, on the fixture the Rust tests pin (tests/fixtures)."""

import shutil

import pytest
import torch
from safetensors.torch import load_file

from conftest import FIXTURES
from unica_train.dataset import ACTIONS, BakedDataset, DatasetError


def test_positions_and_normalisation_match_rust(quick_dataset_dir):
    data = BakedDataset(quick_dataset_dir)
    expected = load_file(str(FIXTURES / "dataset_expected.safetensors"))
    points = data.positions(2, list(range(4, 8)))
    # f32 sums in another order: positions are ~1 m, 1e-5 m is far below a pixel.
    torch.testing.assert_close(points, expected["clip2_frames4to7_positions"], atol=1e-5, rtol=0)
    unit, root = data.normalise(points)
    torch.testing.assert_close(root, expected["clip2_frames4to7_root"], atol=1e-5, rtol=0)
    torch.testing.assert_close(unit, expected["clip2_frames4to7_normalised"], atol=1e-5, rtol=0)
    # The stored root path is the waist mean of each frame.
    torch.testing.assert_close(data.root(points), data.clips[2]["root"][4:8], atol=1e-5, rtol=0)
    assert abs(float(data.root(unit[2]).mean()) - 0.5) < 1e-6


def test_groups_labels_and_switches(quick_dataset_dir):
    data = BakedDataset(quick_dataset_dir)
    groups = data.groups()
    frames = [c["actions"].shape[0] for c in data.clips]
    assert len(groups) == sum(f - 3 for f in frames)
    for g in groups:
        assert g.action == int(data.clips[g.clip]["actions"][g.start + 2])
    # Clip 2 switches Forward -> Left at frame 12: the first group after it targets frame 12.
    clip2 = [g for g in groups if g.clip == 2]
    assert [g.after_switch for g in clip2].index(True) == 12 - 3
    assert ACTIONS[clip2[0].action] == "Forward" and ACTIONS[clip2[-1].action] == "Left"
    assert not any(g.after_switch for g in groups if g.clip == 0), "a one-action clip has no switch"


def test_maps_put_values_on_the_foreground_only(quick_dataset_dir):
    data = BakedDataset(quick_dataset_dir)
    unit, _ = data.normalise(data.positions(1, [0, 1, 2, 3]))
    maps = data.to_maps(unit)
    assert maps.shape == (4, 3, 128, 128)
    mask = data.mask()
    assert int(mask.sum()) == data.manifest["foreground_pixels"]
    assert float((maps * (1 - mask)).abs().max()) == 0.0
    assert float(maps[:, :, mask[0] > 0].min()) > 0.0


def test_broken_datasets_name_the_file(quick_dataset_dir, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(quick_dataset_dir, broken)
    clip = broken / "clips" / "clip_001.safetensors"
    tensors = load_file(str(clip))
    del tensors["root"]
    from safetensors.torch import save_file

    save_file(tensors, str(clip))
    with pytest.raises(DatasetError, match="clip_001.safetensors.*'root' is missing"):
        BakedDataset(broken)
    (broken / "manifest.json").write_text("{")
    with pytest.raises(DatasetError, match="manifest.json"):
        BakedDataset(broken)
