"""Analytic light fields for the tests of flow/'s scripts: a textured fronto-parallel plane at a known
disparity seen by an n x n grid of views, as arrays, as the network's input tensors and as HCI-layout
folders, and a tiny disparity network fitted to such planes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from lfusd.data import formats

N = 9  # HCI's 9x9 grid


def plane_views(d: float, rng: np.random.Generator, size: int = 24, n: int = N) -> np.ndarray:
    """[n*n, size, size, 3] in [0, 1]: a fronto-parallel plane at disparity ``d`` seen by an n x n grid,
    row-major from the top-left view. The centre view shows the texture T; by CONVENTIONS.md a point at
    (u, v) of the centre view is at (u - d*sx, v - d*sy) in view (r, c) with (sx, sy) = (c - n//2, r - n//2),
    so that view shows T(x + d*sx, y + d*sy): T is analytic (sinusoids), so every view is exact."""
    k = rng.uniform(0.25, 0.9, (3, 4, 2)) * rng.choice([-1, 1], (3, 4, 2))
    phase = rng.uniform(0, 2 * np.pi, (3, 4))
    y, x = np.mgrid[0:size, 0:size].astype(float)
    out = []
    for r in range(n):
        for c in range(n):
            xs, ys = x + d * (c - n // 2), y + d * (r - n // 2)
            img = [0.5 + 0.12 * np.sin(k[ch, :, 0, None, None] * xs + k[ch, :, 1, None, None] * ys + phase[ch, :, None, None]).sum(0)
                   for ch in range(3)]
            out.append(np.stack(img, -1))
    return np.clip(np.stack(out), 0, 1).astype(np.float32)


def plane_tensor(d: float, rng: np.random.Generator, size: int = 24, n: int = N) -> torch.Tensor:
    """:func:`plane_views` as the networks take views: [1, n*n, 3, size, size]."""
    return torch.from_numpy(plane_views(d, rng, size, n).transpose(0, 3, 1, 2).copy())[None]


def centre_offsets(n: int = N) -> torch.Tensor:
    """[1, n*n, 2] (sx, sy) of the views of an n x n grid, row-major, from its centre view."""
    rows, cols = np.divmod(np.arange(n * n), n)
    return torch.from_numpy(np.stack([cols - n // 2, rows - n // 2], 1).astype(np.float32))[None]


def write_hci(folder: Path, views: np.ndarray, bits: int = 8) -> Path:
    """``views`` ([N*N, H, W, 3] in [0, 1]) as an HCI-layout folder: input_Cam000.png ... at ``bits``
    bits, and a parameters.cfg that the scripts must not need."""
    folder.mkdir(parents=True)
    scale, dtype = (255, np.uint8) if bits == 8 else (65535, np.uint16)
    for i, v in enumerate(views):
        formats.write_png(folder / f"input_Cam{i:03d}.png", np.round(v * scale).astype(dtype))
    (folder / "parameters.cfg").write_text("[not read]\n")  # present in HCI folders; must not be needed
    return folder


def fit_planes(net: torch.nn.Module, steps: int, d_max: float, size: int, seed: int = 0) -> None:
    """Train the disparity network ``net`` (of a 9x9 grid) for ``steps`` Adam steps on random planes
    at disparities within +-``d_max`` (views of ``size`` pixels, the inner part scored), on one
    thread: toy tensors gain nothing from more, and on a busy machine extra threads spin."""
    rng = np.random.default_rng(seed)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    rel = centre_offsets()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for _ in range(steps):
            d = float(rng.uniform(-d_max, d_max))
            loss = (net(plane_tensor(d, rng, size), rel)[0, 4:-4, 4:-4] - d).abs().mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
    finally:
        torch.set_num_threads(threads)
