"""The committed engine fixtures (tests/fixtures/nn) are what the trainer computes now;
regenerate with `python -m unica_train.fixtures --out tests/fixtures/nn`."""

import torch
from safetensors.torch import load_file

from conftest import FIXTURES
from unica_train.fixtures import build


def test_committed_nn_fixtures_are_current():
    built = build()
    folder = FIXTURES / "nn"
    on_disk = sorted(p.stem for p in folder.glob("*.safetensors"))
    assert on_disk == sorted(built), "fixture files differ; regenerate (see the module docstring)"
    for name, tensors in built.items():
        saved = load_file(str(folder / f"{name}.safetensors"))
        assert sorted(saved) == sorted(tensors), name
        for key, value in tensors.items():
            # The same code on another CPU or torch build rounds differently, and a whole
            # UNet pass chains hundreds of those roundings: witch_one_pass_frame's z (|z|
            # up to 5) differed by 3.5e-5 between two CPUs. A changed trainer moves the
            # outputs by far more than 1e-4 of their scale.
            scale = max(1.0, float(saved[key].abs().max())) if saved[key].numel() else 1.0
            torch.testing.assert_close(saved[key], value, atol=1e-4 * scale, rtol=0, msg=f"{name}:{key}")
