"""Learned appearance costs of a torch appearance network between the boxes of two images (for
building training trials; the deployed runtime uses the exported ONNX network instead)."""

from __future__ import annotations

import numpy as np
import torch

from xvmatch.formats.crops import box_crops
from xvmatch.models.appearance_net import AppearanceNet, appearance_distance

__all__ = ["AppearanceCoster"]


class AppearanceCoster:
    """Learned appearance costs between the boxes of two images.

    Crops every box as in training (:func:`~xvmatch.formats.crops.box_crops`, the
    network's input size from its weights record), embeds them with the network in eval mode
    and returns ``|a - b| / 2``.

    Args:
        net: the trained network.
        device: where to run it.
        batch_size: crops per forward pass.
        context: relative margin around each box (as in training).
    """

    def __init__(self, net: AppearanceNet, *, device: str | torch.device = "cpu",
                 batch_size: int = 256, context: float = 0.1) -> None:
        self.net = net.eval().to(device)
        self.device = torch.device(device)
        self.batch_size = int(batch_size)
        self.context = float(context)

    @torch.no_grad()
    def embed(self, image: np.ndarray, boxes: np.ndarray) -> torch.Tensor:
        """``(K, D)`` descriptors of the ``(K, 4)`` boxes of ``image`` (BGR uint8)."""
        crops = box_crops(image, boxes, self.net.preprocessing.crop_size, self.context)
        if crops.shape[0] == 0:
            return torch.zeros(0, self.net.embedding_dim, device=self.device)
        out = []
        for k in range(0, crops.shape[0], self.batch_size):
            chunk = torch.from_numpy(crops[k : k + self.batch_size]).to(self.device)
            out.append(self.net.embed_crops(chunk))
        return torch.cat(out)

    def __call__(self, top_image: np.ndarray, top_boxes: np.ndarray, ego_image: np.ndarray,
                 ego_boxes: np.ndarray) -> np.ndarray:
        """``(M, N)`` appearance costs in [0, 1] between top and egocentric boxes."""
        top = self.embed(top_image, top_boxes)
        ego = self.embed(ego_image, ego_boxes)
        return appearance_distance(top, ego).double().cpu().numpy()
