"""The Python dataset reader against the Rust one: same positions (LBS + gather), same
group normalisation, on the fixture the Rust tests pin (tests/fixtures)."""

import shutil

import pytest
import torch
from safetensors.torch import load_file

from conftest import FIXTURES
from unica_train.dataset import ACTIONS, QUARTER_TURN_ACTION, BakedDataset, DatasetError, quarter_turn, quarter_turn_action


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


# The world direction each key moves toward (src/avatar/locomotion.rs action_direction).
DIRECTIONS = {"Forward": (0.0, 0.0, 1.0), "Backward": (0.0, 0.0, -1.0), "Left": (1.0, 0.0, 0.0), "Right": (-1.0, 0.0, 0.0)}


def test_a_quarter_turn_turns_points_and_actions_together(quick_dataset_dir):
    p = torch.tensor([1.0, 2.0, 3.0])
    assert quarter_turn(p).tolist() == [3.0, 2.0, -1.0]
    assert quarter_turn(p, 2).tolist() == [-1.0, 2.0, -3.0]
    assert quarter_turn(p, 4).tolist() == p.tolist() and quarter_turn(p, 0).tolist() == p.tolist()
    # A heading of 0 (+Z) becomes 90° (+X): the turn the app's headings call positive.
    d = quarter_turn(torch.tensor([0.0, 0.0, 1.0]))
    assert float(torch.rad2deg(torch.atan2(d[0], d[2]))) == 90.0
    # Each key's direction, turned, is the direction of the key its label becomes.
    assert QUARTER_TURN_ACTION[0] == 0 and sorted(QUARTER_TURN_ACTION) == [0, 1, 2, 3, 4]
    for name, direction in DIRECTIONS.items():
        a = ACTIONS.index(name)
        assert quarter_turn(torch.tensor(direction)).tolist() == list(DIRECTIONS[ACTIONS[QUARTER_TURN_ACTION[a]]]), name
        assert quarter_turn_action(a, 4) == a and quarter_turn_action(a, 2) == QUARTER_TURN_ACTION[QUARTER_TURN_ACTION[a]]
    # On the teacher's data: clip 1 runs Forward; turned, its root runs the way Left goes.
    data = BakedDataset(quick_dataset_dir)
    clip = data.clips[1]
    assert ACTIONS[int(clip["actions"][-1])] == "Forward"
    world = quarter_turn(data.positions(1, list(range(clip["actions"].shape[0]))))
    path = data.root(world)
    step = path[-1] - path[int(clip["switch"])]
    step = torch.stack([step[0], step[2]]) / torch.stack([step[0], step[2]]).norm()
    left = DIRECTIONS[ACTIONS[quarter_turn_action(ACTIONS.index("Forward"))]]
    assert ACTIONS[quarter_turn_action(ACTIONS.index("Forward"))] == "Left"
    assert float(step @ torch.tensor([left[0], left[2]])) > 0.95


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
