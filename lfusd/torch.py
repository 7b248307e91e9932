"""PyTorch entry points: ``lfusd.torch.LightFieldVideoDataset``, ``data_loader`` and ``worker_init_fn``
(see lfusd.data.torch; the augmentations are lfusd.data.augment).

This module is ``lfusd.torch``; with absolute imports (Python 3) ``import torch`` anywhere in the
package still means PyTorch itself.
"""

from __future__ import annotations

from lfusd.data.torch import KEYS, LightFieldVideoDataset, data_loader, select_views, worker_init_fn

__all__ = ["KEYS", "LightFieldVideoDataset", "data_loader", "select_views", "worker_init_fn"]
