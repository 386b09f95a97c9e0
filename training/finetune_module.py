"""Fine-tuning a pretrained appearance trunk: frozen early layers and a lower trunk learning rate.

:class:`FinetuneAppearanceModule` is :class:`~xvmatch.training.appearance_module.
AppearanceModule` (same steps, loss and metrics, Section 3.3.2 of the CVMHAT paper) with two
options for an ImageNet-initialised trunk (``models/pretrained_backbones.py``):

* ``frozen``: sub-modules of the network (names as ``net.get_submodule`` takes them, e.g.
  ``trunk.features.0``) whose parameters are not trained and whose batch normalisation keeps its
  ImageNet statistics (held in eval mode in training too). No gradient flows through them, so a
  frozen stem saves most of its backward pass.
* ``trunk_lr_scale``: the trunk's peak learning rate over the head's (``lr``); the same warm-up
  and cosine decay apply to both.

The saved network is the plain :class:`~xvmatch.models.appearance_net.AppearanceNet`: freezing
is a training-time choice, so weights files and exports are unchanged.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from xvmatch.training.appearance_module import AppearanceModule

__all__ = ["FinetuneAppearanceModule"]


class FinetuneAppearanceModule(AppearanceModule):
    """:class:`AppearanceModule` with frozen sub-modules and a separate trunk learning rate.

    Args:
        net: the network shared by both views; it must have a ``trunk`` attribute when
            ``trunk_lr_scale`` is not 1.
        margin, hard_negatives, lr, weight_decay, warmup_steps, final_lr_ratio,
            geo_hard_weight: as :class:`AppearanceModule` (``lr``: the head's peak).
        trunk_lr_scale: the trunk's peak learning rate over ``lr`` (> 0).
        frozen: names of sub-modules of ``net`` left untrained, in eval mode throughout.

    Raises:
        ValueError: a name that is not a sub-module of ``net``, a non-positive
            ``trunk_lr_scale``, or one other than 1 for a network without ``trunk``.
    """

    def __init__(
        self,
        net: nn.Module,
        margin: float = 0.5,
        hard_negatives: int = 2,
        lr: float = 1e-3,
        weight_decay: float = 1e-4,
        warmup_steps: int = 50,
        final_lr_ratio: float = 0.05,
        geo_hard_weight: float = 0.0,
        trunk_lr_scale: float = 1.0,
        frozen: Sequence[str] = (),
    ) -> None:
        super().__init__(net, margin, hard_negatives, lr, weight_decay, warmup_steps,
                         final_lr_ratio, geo_hard_weight)
        if not float(trunk_lr_scale) > 0:
            raise ValueError(f"trunk_lr_scale must be > 0, got {trunk_lr_scale}")
        if float(trunk_lr_scale) != 1.0 and not isinstance(getattr(net, "trunk", None),
                                                           nn.Module):
            raise ValueError("trunk_lr_scale needs a network with a trunk attribute, got "
                             f"{type(net).__name__}")
        if isinstance(frozen, str):
            frozen = [frozen]
        modules = []
        for name in frozen:
            try:
                modules.append(net.get_submodule(str(name)))
            except AttributeError:
                raise ValueError(f"frozen: {name!r} is not a sub-module of the network "
                                 f"(e.g. trunk.features.0)") from None
        self._frozen: list[nn.Module] = modules
        for module in modules:
            module.requires_grad_(False)
        self.train(self.training)

    def train(self, mode: bool = True) -> FinetuneAppearanceModule:
        """Set the training mode, keeping the frozen sub-modules in eval mode."""
        super().train(mode)
        for module in getattr(self, "_frozen", ()):
            module.eval()
        return self

    def configure_optimizers(self):
        """AdamW over the trainable parameters in two groups, head (``lr``) and trunk
        (``lr * trunk_lr_scale``), under :class:`AppearanceModule`'s warm-up and cosine
        schedule."""
        base = super().configure_optimizers()
        schedule = base["lr_scheduler"]["scheduler"].lr_lambdas[0]
        hp = self.hparams
        trunk = getattr(self.net, "trunk", None)
        in_trunk = set() if trunk is None else {id(p) for p in trunk.parameters()}
        params = [p for p in self.parameters() if p.requires_grad]
        groups = [
            {"params": [p for p in params if id(p) not in in_trunk], "lr": hp.lr},
            {"params": [p for p in params if id(p) in in_trunk],
             "lr": hp.lr * float(hp.trunk_lr_scale)},
        ]
        groups = [g for g in groups if g["params"]]
        optimizer = torch.optim.AdamW(groups, lr=hp.lr, weight_decay=hp.weight_decay)
        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, [schedule] * len(groups))
        return {"optimizer": optimizer,
                "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}
