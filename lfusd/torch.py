"""PyTorch entry points: ``lfusd.torch.LightFieldVideoDataset`` (see lfusd.data.torch).

This module is ``lfusd.torch``; with absolute imports (Python 3) ``import torch`` anywhere in the
package still means PyTorch itself.
"""

from __future__ import annotations

from lfusd.data.torch import KEYS, LightFieldVideoDataset, select_views

__all__ = ["KEYS", "LightFieldVideoDataset", "select_views"]
