"""Compact PyTorch re-implementations of the disentangling networks of Wang et al.,
"Disentangling light fields for super-resolution and disparity estimation", TPAMI 2022
(code: github.com/YingqianWang/DistgDisp, DistgSSR, DistgASR).

The idea: arrange the U x V views of a light field as one macro-pixel image (MacPI; pixel
(h, w) of view (u, v) at (h*U + u, w*V + v)) and let ordinary 2-D convolutions pick out one
sub-space each:

- spatial: 3x3 convolution with dilation = angRes (each macro-pixel's views stay apart);
- angular: kernel = stride = angRes (one macro-pixel, all views of one spatial position);
- EPI: kernel [1, angRes*k], stride [1, angRes] along MacPI rows (horizontal EPIs; the same
  weights on the transposed MacPI give the vertical ones).

:class:`DistgBlock` fuses the three (as DistgASR/DistgSSR's block). :class:`DisparityNet` follows
DistgDisp: features per view, a cost volume whose entry for disparity candidate d is the angular
("disparity-selective") convolution of the views sheared by d, 3-D aggregation, and a soft-argmin
regression. DistgDisp shears with integer dilations of that convolution; here the views are shifted
with bilinear sampling by d times their own offsets, so candidates can be fractional and rigs need
not be uniform. :class:`ASRNet` follows DistgASR (2x2 -> NxN angular super-resolution): Distg
blocks on the input views, an angular convolution to one feature per position, a 1x1 expansion to
N*N views and a pixel shuffle into the output MacPI. Unlike DistgASR, the network adds its output
to the angular bilinear blend of the corners (a global residual), which lets a toy run learn in
a minute. Both use LeakyReLU and no normalisation layers (small batches).
"""

from __future__ import annotations

import numpy as np

import torch
import torch.nn as nn
import torch.nn.functional as F


def sai_to_macpi(x: torch.Tensor) -> torch.Tensor:
    """[B, C, U, V, H, W] sub-aperture views -> [B, C, H*U, W*V] macro-pixel image."""
    b, c, u, v, h, w = x.shape
    return x.permute(0, 1, 4, 2, 5, 3).reshape(b, c, h * u, w * v)


def macpi_to_sai(x: torch.Tensor, u: int, v: int) -> torch.Tensor:
    """[B, C, H*U, W*V] macro-pixel image -> [B, C, U, V, H, W] views."""
    b, c, hu, wv = x.shape
    return x.reshape(b, c, hu // u, u, wv // v, v).permute(0, 1, 3, 5, 2, 4)


def _act() -> nn.Module:
    return nn.LeakyReLU(0.1, inplace=True)


class PixelShuffle1D(nn.Module):
    """[B, r*C, H, W] -> [B, C, H, W*r]: channel block i becomes column offset i (EPI upsampling)."""

    def __init__(self, r: int):
        super().__init__()
        self.r = r

    def forward(self, x):
        b, rc, h, w = x.shape
        c = rc // self.r
        return x.reshape(b, self.r, c, h, w).permute(0, 2, 3, 4, 1).reshape(b, c, h, w * self.r)


class DistgBlock(nn.Module):
    """Spatial, angular and EPI feature extractors on a MacPI, fused by a 1x1 conv, with a residual."""

    def __init__(self, ang: int, ch: int):
        super().__init__()
        # an EPI kernel spans k whole macro-pixels centred on the output's own (k odd)
        k = ang if ang % 2 else ang + 1
        self.angular = nn.Sequential(nn.Conv2d(ch, ch, ang, stride=ang, bias=False), _act(), nn.Conv2d(ch, ch * ang * ang, 1, bias=False), nn.PixelShuffle(ang))
        self.epi = nn.Sequential(
            nn.Conv2d(ch, ch, (1, ang * k), stride=(1, ang), padding=(0, ang * (k - 1) // 2), bias=False),
            _act(),
            nn.Conv2d(ch, ch * ang, 1, bias=False),
            PixelShuffle1D(ang),
        )
        self.fuse = nn.Sequential(nn.Conv2d(4 * ch, ch, 1, bias=False), _act())
        self.spatial = nn.Sequential(
            nn.Conv2d(ch, ch, 3, padding=ang, dilation=ang, bias=False), _act(), nn.Conv2d(ch, ch, 3, padding=ang, dilation=ang, bias=False)
        )

    def forward(self, x):
        epi_h = self.epi(x)
        epi_v = self.epi(x.transpose(2, 3)).transpose(2, 3)  # square angular grid: one set of weights
        f = self.fuse(torch.cat([x, self.angular(x), epi_h, epi_v], 1))
        return x + self.spatial(f)


def shift_views(feat: torch.Tensor, rel: torch.Tensor, d: float) -> torch.Tensor:
    """Resample views to the reference position for disparity d (CONVENTIONS.md, light-field grid):
    the reference pixel (u, v) is seen at (u - d*sx, v - d*sy) in a view at relative offset (sx, sy).

    feat [B, N, C, H, W], rel [B, N, 2] -> [B, N, C, H, W] (zeros outside the image).
    """
    b, n, c, h, w = feat.shape
    ys, xs = torch.meshgrid(torch.arange(h, device=feat.device, dtype=feat.dtype), torch.arange(w, device=feat.device, dtype=feat.dtype), indexing="ij")
    u = xs - d * rel[..., 0, None, None]  # B,N,H,W
    v = ys - d * rel[..., 1, None, None]
    grid = torch.stack([2 * u / max(w - 1, 1) - 1, 2 * v / max(h - 1, 1) - 1], -1).reshape(b * n, h, w, 2)
    out = F.grid_sample(feat.reshape(b * n, c, h, w), grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    return out.reshape(b, n, c, h, w)


class ResBlock3D(nn.Module):
    def __init__(self, ch: int):
        super().__init__()
        self.body = nn.Sequential(nn.Conv3d(ch, ch, 3, padding=1, bias=False), _act(), nn.Conv3d(ch, ch, 3, padding=1, bias=False))

    def forward(self, x):
        return x + self.body(x)


class DisparityNet(nn.Module):
    """DistgDisp-like disparity of the reference view of a square U x U light field.

    forward(views [B, U*U, C, H, W] row-major, rel [B, U*U, 2] offsets from the reference view in
    baselines) -> disparity [B, H, W] in pixels per baseline step, a softmax-weighted mean of the
    candidates linspace(d_min, d_max, n_disp).
    """

    def __init__(self, ang: int, d_min: float, d_max: float, n_disp: int = 9, in_ch: int = 3, ch: int = 16, n_blocks: int = 2, cost_ch: int = 32):
        super().__init__()
        self.ang = ang
        self.feature = nn.Sequential(nn.Conv2d(in_ch, ch, 3, padding=ang, dilation=ang, bias=False), _act(), *[DistgBlock(ang, ch) for _ in range(n_blocks)])
        # DistgDisp's disparity-selective angular feature extractor: one macro-pixel of sheared views
        self.dsafe = nn.Conv2d(ch, cost_ch, ang, stride=ang, bias=False)
        self.aggregate = nn.Sequential(nn.Conv3d(cost_ch, cost_ch, 3, padding=1, bias=False), _act(), ResBlock3D(cost_ch), nn.Conv3d(cost_ch, 1, 3, padding=1, bias=False))
        self.register_buffer("candidates", torch.linspace(float(d_min), float(d_max), int(n_disp)))

    def cost_volume(self, views: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
        b, n, c, h, w = views.shape
        a = self.ang
        x = sai_to_macpi(views.reshape(b, a, a, c, h, w).permute(0, 3, 1, 2, 4, 5))
        f = macpi_to_sai(self.feature(x), a, a)  # B,C,U,V,H,W
        f = f.permute(0, 2, 3, 1, 4, 5).reshape(b, n, -1, h, w)
        costs = []
        for d in self.candidates.tolist():
            s = shift_views(f, rel, d)
            costs.append(self.dsafe(sai_to_macpi(s.reshape(b, a, a, -1, h, w).permute(0, 3, 1, 2, 4, 5))))
        return torch.stack(costs, 2)  # B,C,D,H,W

    def forward(self, views: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
        if views.shape[1] != self.ang * self.ang:
            raise ValueError(f"DisparityNet({self.ang}x{self.ang}) got {views.shape[1]} views")
        score = self.aggregate(self.cost_volume(views, rel.to(views.dtype)))[:, 0]  # B,D,H,W
        p = torch.softmax(score, 1)
        return (p * self.candidates[None, :, None, None]).sum(1)


def star_views(ang: int) -> list[int]:
    """Row-major indices of the views on the reference view's row, column and two diagonals of a
    U x U grid (EPINet's four EPI directions; the reference is the HCI centre, index U*U // 2)."""
    c = (ang * ang // 2) // ang, (ang * ang // 2) % ang
    return [r * ang + q for r in range(ang) for q in range(ang) if r == c[0] or q == c[1] or abs(r - c[0]) == abs(q - c[1])]


class StarDisparityNet(nn.Module):
    """DisparityNet's idea (a learned angular "disparity-selective" projection of views sheared by
    each candidate, 3-D aggregation, soft-argmin) at a fraction of its CPU cost (issue 36):

    - only the views of the reference's row, column and diagonals (:func:`star_views`: 33 of 9x9);
    - features per view by plain 2-D convolutions (shared weights) at half resolution;
    - the angular projection is linear, so each view's features are projected to ``cost_ch``
      channels once (its own weights, a grouped 1x1 convolution) and only then sheared and summed
      per candidate: sum_i W_i shift_i(f_i) = sum_i shift_i(W_i f_i); the cost volume and its 3-D
      aggregation are at half resolution;
    - the soft-argmin disparity is upsampled and corrected by a small full-resolution refinement
      that sees the reference view (coarse to fine).

    Same forward contract as :class:`DisparityNet` for odd grids whose reference is the centre view;
    the offsets ``rel`` of the views left out are not used.
    """

    def __init__(self, ang: int, d_min: float, d_max: float, n_disp: int = 17, in_ch: int = 3, ch: int = 16, n_blocks: int = 3, cost_ch: int = 16):
        super().__init__()
        if ang % 2 == 0:  # the star and the refinement need the reference at the grid's centre
            raise ValueError(f"StarDisparityNet needs an odd grid (its reference is the centre view), got {ang}x{ang}")
        self.ang = ang
        self.register_buffer("views", torch.tensor(star_views(ang)), persistent=False)
        self.ref = ang * ang // 2
        n = len(self.views)
        # kernel 4, stride 2, padding 1: half-resolution pixel i is centred on full-resolution i*2 + 0.5
        self.stem = nn.Sequential(nn.Conv2d(in_ch, ch, 4, stride=2, padding=1), _act())
        self.blocks = nn.ModuleList(nn.Sequential(nn.Conv2d(ch, ch, 3, padding=1), _act()) for _ in range(n_blocks))
        self.project = nn.Conv2d(n * ch, n * cost_ch, 1, groups=n, bias=False)
        self.aggregate = nn.Sequential(_act(), nn.Conv3d(cost_ch, cost_ch, 3, padding=1, bias=False), _act(), ResBlock3D(cost_ch),
                                       nn.Conv3d(cost_ch, 1, 3, padding=1, bias=False))
        self.refine = nn.Sequential(nn.Conv2d(in_ch + 1, ch, 3, padding=1), _act(), nn.Conv2d(ch, ch, 3, padding=2, dilation=2), _act(),
                                    nn.Conv2d(ch, 1, 3, padding=1))
        self.register_buffer("candidates", torch.linspace(float(d_min), float(d_max), int(n_disp)))

    def features(self, x: torch.Tensor) -> torch.Tensor:
        x = self.stem(x)
        for b in self.blocks:
            x = x + b(x)
        return x

    def coarse(self, views: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
        """Soft-argmin disparity [B, h, w] at half resolution (full-resolution pixels per view step)."""
        b, _, c, h, w = views.shape
        sel = views[:, self.views]
        n = sel.shape[1]
        f = self.features(sel.reshape(b * n, c, h, w))
        hh, ww = f.shape[-2:]
        g = self.project(f.reshape(b, -1, hh, ww)).reshape(b, n, -1, hh, ww)
        r = rel[:, self.views] * 0.5  # half-resolution pixels (stride 2) per view step
        costs = [shift_views(g, r, d).sum(1) for d in self.candidates.tolist()]
        score = self.aggregate(torch.stack(costs, 2))[:, 0]  # B,D,h,w
        return (torch.softmax(score, 1) * self.candidates[None, :, None, None]).sum(1)

    def forward(self, views: torch.Tensor, rel: torch.Tensor) -> torch.Tensor:
        if views.shape[1] != self.ang * self.ang:
            raise ValueError(f"StarDisparityNet({self.ang}x{self.ang}) got {views.shape[1]} views")
        if rel[:, self.ref].abs().max() > 1e-6:
            raise ValueError("StarDisparityNet's reference is the centre view: rel must be offsets from it")
        h, w = views.shape[-2:]
        d = F.interpolate(self.coarse(views, rel.to(views.dtype))[:, None], size=(h, w), mode="bilinear", align_corners=False)
        return (d + self.refine(torch.cat([views[:, self.ref], d], 1)))[:, 0]


def blend_corners(corners: torch.Tensor, n: int) -> torch.Tensor:
    """Angular bilinear blend: corners [B, 4, C, H, W] ((0,0), (0,n-1), (n-1,0), (n-1,n-1)) -> [B, n*n, C, H, W]."""
    t = torch.linspace(0.0, 1.0, n, device=corners.device, dtype=corners.dtype)
    ay, ax = torch.meshgrid(t, t, indexing="ij")
    w = torch.stack([(1 - ay) * (1 - ax), (1 - ay) * ax, ay * (1 - ax), ay * ax], -1).reshape(n * n, 4)
    return torch.einsum("vk,bkchw->bvchw", w, corners)


class ASRNet(nn.Module):
    """DistgASR-like angular super-resolution: 2x2 corner views -> all n x n views.

    forward(corners [B, 4, C, H, W] row-major) -> [B, n*n, C, H, W] row-major.
    """

    def __init__(self, n: int, in_ch: int = 3, ch: int = 32, n_blocks: int = 2):
        super().__init__()
        self.n = n
        self.head = nn.Sequential(nn.Conv2d(in_ch, ch, 3, padding=2, dilation=2, bias=False), _act())
        self.blocks = nn.Sequential(*[DistgBlock(2, ch) for _ in range(n_blocks)])
        self.upsample = nn.Sequential(
            nn.Conv2d(ch, ch, 2, stride=2, bias=False),  # angular: one feature per spatial position
            _act(),
            nn.Conv2d(ch, ch * n * n, 1, bias=False),
            nn.PixelShuffle(n),  # -> the n x n output MacPI
            nn.Conv2d(ch, in_ch, 3, padding=n, dilation=n, bias=False),
        )

    def forward(self, corners: torch.Tensor) -> torch.Tensor:
        b, k, c, h, w = corners.shape
        if k != 4:
            raise ValueError(f"ASRNet takes the 4 corner views, got {k}")
        x = sai_to_macpi(corners.reshape(b, 2, 2, c, h, w).permute(0, 3, 1, 2, 4, 5))
        r = macpi_to_sai(self.upsample(self.blocks(self.head(x))), self.n, self.n)  # B,C,n,n,H,W
        return blend_corners(corners, self.n) + r.permute(0, 2, 3, 1, 4, 5).reshape(b, self.n * self.n, c, h, w)


# ---- scene flow ---------------------------------------------------------------------------------


def backward_warp(x: torch.Tensor, flow: torch.Tensor) -> torch.Tensor:
    """x [B, C, H, W] sampled at (u, v) + flow [B, 2, H, W] (bilinear, zeros outside)."""
    b, _, h, w = x.shape
    ys, xs = torch.meshgrid(torch.arange(h, device=x.device, dtype=x.dtype), torch.arange(w, device=x.device, dtype=x.dtype), indexing="ij")
    u, v = xs + flow[:, 0], ys + flow[:, 1]
    grid = torch.stack([2 * u / max(w - 1, 1) - 1, 2 * v / max(h - 1, 1) - 1], -1)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="zeros", align_corners=True)


def local_correlation(f1: torch.Tensor, f2: torch.Tensor, radius: int) -> torch.Tensor:
    """PWC-Net's cost volume: [B, (2r+1)^2, H, W], the mean over channels of f1 times f2 shifted by
    every (dx, dy) in [-r, r]^2 (zeros outside), row-major over (dy, dx)."""
    b, c, h, w = f1.shape
    p = F.pad(f2, (radius, radius, radius, radius))
    out = [(f1 * p[:, :, dy : dy + h, dx : dx + w]).mean(1) for dy in range(2 * radius + 1) for dx in range(2 * radius + 1)]
    return torch.stack(out, 1)


def _conv(i: int, o: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(i, o, 3, stride=stride, padding=1), _act())


class FlowNet(nn.Module):
    """PWC-lite optical flow of two images: a shared feature pyramid (``levels`` levels, each at half
    the resolution of the one above, the finest at 1/2), at each level from the coarsest a local
    correlation of frame t's features with frame t+1's warped by the upsampled flow and a small
    decoder for the residual flow; the finest flow is upsampled bilinearly to full resolution.

    forward(img0, img1 [B, 3, H, W]) -> flow [B, 2, H, W] in pixels (frame t -> t+1). H and W need not
    be multiples of anything (levels are resized to fit).
    """

    def __init__(self, ch: int = 16, levels: int = 3, radius: int = 3):
        super().__init__()
        self.radius = radius
        chans = [ch * 2**i for i in range(levels)]
        enc, prev = [], 3
        for c in chans:
            enc.append(nn.Sequential(_conv(prev, c, 2), _conv(c, c)))
            prev = c
        self.encoder = nn.ModuleList(enc)
        corr = (2 * radius + 1) ** 2
        self.decoders = nn.ModuleList(nn.Sequential(_conv(corr + c + 2, 2 * ch), _conv(2 * ch, ch), nn.Conv2d(ch, 2, 3, padding=1)) for c in chans)

    def pyramid(self, x):
        feats = []
        for e in self.encoder:
            x = e(x)
            feats.append(x)
        return feats

    def forward(self, img0: torch.Tensor, img1: torch.Tensor) -> torch.Tensor:
        p0, p1 = self.pyramid(img0), self.pyramid(img1)
        flow = None
        for lvl in reversed(range(len(p0))):
            f0, f1 = p0[lvl], p1[lvl]
            if flow is None:
                flow = f0.new_zeros(f0.shape[0], 2, *f0.shape[-2:])
            else:
                flow = _resize_flow(flow, f0.shape[-2:])
            corr = local_correlation(f0, backward_warp(f1, flow), self.radius)
            flow = flow + self.decoders[lvl](torch.cat([corr, f0, flow], 1))
        return _resize_flow(flow, img0.shape[-2:])


class DISRefineFlow(nn.Module):
    """Optical flow of two images: OpenCV's DIS flow (lfusd.evaluation.baselines.dis_flow, the one
    the plane sweep + DIS composition uses) plus a residual from a small CNN that sees frame t,
    frame t+1 warped back by the DIS flow, their difference and the DIS flow; dilated convolutions
    (rates 1, 2, 4, ... over ``blocks`` layers) give it context to correct occlusions, motion
    boundaries and textureless regions. The residual's last layer starts at zero, so an untrained
    network is DIS exactly. DIS runs on the CPU without gradients (the images as 8-bit grey).

    A network a CPU can train: a PWC-style FlowNet trained for 700 steps on lfusd's ``things``
    preview learned to predict zero flow everywhere (its decoders had not yet learned to read the
    cost volume); this one starts where the classical baseline is and learns only corrections.

    forward(img0, img1 [B, 3, H, W] in [0, 1]) -> flow [B, 2, H, W] in pixels (frame t -> t+1).
    """

    def __init__(self, ch: int = 32, blocks: int = 5):
        super().__init__()
        layers, prev = [], 3 + 3 + 3 + 2
        for i in range(blocks):
            rate = 2 ** min(i, 4)
            layers += [nn.Conv2d(prev, ch, 3, padding=rate, dilation=rate), _act()]
            prev = ch
        self.body = nn.Sequential(*layers)
        self.head = nn.Conv2d(ch, 2, 3, padding=1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    @staticmethod
    def dis(img0: torch.Tensor, img1: torch.Tensor) -> torch.Tensor:
        from lfusd.evaluation.baselines import dis_flow

        a = img0.detach().float().clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy()
        b = img1.detach().float().clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy()
        flows = [dis_flow(x, y) for x, y in zip(a, b)]
        return torch.from_numpy(np.stack(flows)).permute(0, 3, 1, 2).to(img0)

    def forward(self, img0: torch.Tensor, img1: torch.Tensor) -> torch.Tensor:
        base = self.dis(img0, img1)
        warped = backward_warp(img1, base)
        x = torch.cat([img0, warped, img0 - warped, base / 8.0], 1)
        return base + self.head(self.body(x))


def _resize_flow(flow: torch.Tensor, size) -> torch.Tensor:
    """Bilinear resize of a flow field with its vectors scaled to the new pixel size."""
    h, w = flow.shape[-2:]
    out = F.interpolate(flow, size=tuple(size), mode="bilinear", align_corners=True)
    sx, sy = (size[1] - 1) / max(w - 1, 1), (size[0] - 1) / max(h - 1, 1)
    return torch.stack([out[:, 0] * sx, out[:, 1] * sy], 1)


class SceneFlowNet(nn.Module):
    """Light-field scene flow of the reference view from two frames of a square U x U light field:
    :class:`FlowNet` on the reference view at t and t+1, one disparity network (shared weights:
    :class:`DisparityNet`, or the one given, e.g. a trained :class:`StarDisparityNet`) on the whole
    light field at t and at t+1, and the disparity change of each reference pixel's
    point as the disparity at t+1 sampled where the flow carries the pixel, minus the disparity at t
    (lfusd's ``disparity_change``). Scene flow follows from these through the camera
    (lfusd.evaluation.baselines.scene_flow_from_change).

    forward(views0, views1 [B, U*U, 3, H, W] row-major, rel [B, U*U, 2] offsets from the reference
    view in baselines, ref: the reference view's index) -> dict of ``flow`` [B, 2, H, W],
    ``disparity`` [B, H, W] (t), ``disparity_next`` [B, H, W] (t+1, its own pixels) and
    ``disparity_change`` [B, H, W].
    """

    def __init__(self, ang: int, d_min: float, d_max: float, n_disp: int = 9, ch: int = 16, n_blocks: int = 2, cost_ch: int = 32,
                 flow_ch: int = 16, flow_levels: int = 3, radius: int = 3, disparity: nn.Module | None = None, flow_arch: str = "pwc"):
        super().__init__()
        self.ang = ang
        # ``disparity``: a disparity network of the same forward contract (e.g. a trained StarDisparityNet)
        self.disparity = disparity if disparity is not None else DisparityNet(ang, d_min, d_max, n_disp, ch=ch, n_blocks=n_blocks, cost_ch=cost_ch)
        # "pwc": FlowNet; "dis": DISRefineFlow (OpenCV DIS refined by a CNN)
        self.flow = DISRefineFlow(flow_ch, flow_levels) if flow_arch == "dis" else FlowNet(flow_ch, flow_levels, radius)

    def forward(self, views0: torch.Tensor, views1: torch.Tensor, rel: torch.Tensor, ref: int) -> dict:
        b = views0.shape[0]
        d = self.disparity(torch.cat([views0, views1]), torch.cat([rel, rel]))
        return self.motion(views0[:, ref], views1[:, ref], d[:b], d[b:])

    def motion(self, img0: torch.Tensor, img1: torch.Tensor, d0: torch.Tensor, d1: torch.Tensor) -> dict:
        """The outputs of :meth:`forward` from the reference view's images [B, 3, H, W] and its
        disparities at t and t+1 [B, H, W] (the disparity network's, which a caller predicting
        consecutive pairs computes once per frame)."""
        flow = self.flow(img0, img1)
        d1_at = backward_warp(d1[:, None], flow)[:, 0]
        return {"flow": flow, "disparity": d0, "disparity_next": d1, "disparity_change": d1_at - d0}
