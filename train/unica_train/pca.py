"""PCA of position maps (docs/architecture.md, The geometry model and The live loop): fitted on the training frames' foreground values,
each frame centred on its own root, and used only to clean what is drawn."""

from __future__ import annotations

import torch


def fit(frames: torch.Tensor, components: int) -> tuple[torch.Tensor, torch.Tensor]:
    """frames [M, D] -> (mean [D], basis [K, D] with orthonormal rows), K <= min(M, D)."""
    mean = frames.mean(0)
    centred = (frames - mean).double()
    _, _, vh = torch.linalg.svd(centred, full_matrices=False)
    k = min(components, vh.shape[0])
    return mean, vh[:k].float()


def project(x: torch.Tensor, mean: torch.Tensor, basis: torch.Tensor) -> torch.Tensor:
    """The closest point to x [..., D] in the PCA subspace."""
    return mean + ((x - mean) @ basis.T) @ basis


def coefficients(x: torch.Tensor, mean: torch.Tensor, basis: torch.Tensor) -> torch.Tensor:
    return (x - mean) @ basis.T
