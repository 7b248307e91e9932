"""Measurements of UsdSkel characters made with pxr alone (for the human, gait and animate tests)."""

from __future__ import annotations

import numpy as np
from pxr import Usd, UsdGeom, UsdSkel


def joint_world(stage: Usd.Stage, skel_path: str, frames) -> tuple[list[str], np.ndarray]:
    """(joint leaf names, world joint positions (F, J, 3)) via UsdSkel.SkeletonQuery."""
    skel = UsdSkel.Skeleton(stage.GetPrimAtPath(skel_path))
    root = UsdSkel.Root.Find(skel.GetPrim())
    cache = UsdSkel.Cache()
    cache.Populate(root, Usd.PrimDefaultPredicate)
    query = cache.GetSkelQuery(skel)
    names = [str(j).split("/")[-1] for j in query.GetJointOrder()]
    out = []
    for f in frames:
        world = query.ComputeJointWorldTransforms(UsdGeom.XformCache(Usd.TimeCode(float(f))))
        out.append([np.array(m)[3, :3] for m in world])
    return names, np.array(out)


def planted_steps(ankle: np.ndarray, ground_z: np.ndarray, tol: float = 0.005) -> list[tuple[int, int, float]]:
    """Stances of one foot: runs of frames whose ankle is within ``tol`` of its lowest height above
    the ground; returns (first index, last index, largest distance from the first position)."""
    h = ankle[:, 2] - ground_z
    down = h < h.min() + tol
    steps, i = [], 0
    while i < len(down):
        if not down[i]:
            i += 1
            continue
        j = i
        while j + 1 < len(down) and down[j + 1]:
            j += 1
        slide = float(np.linalg.norm(ankle[i : j + 1] - ankle[i], axis=1).max())
        steps.append((i, j, slide))
        i = j + 1
    return steps


CONTACT = 0.005  # a sole point this close to the ground touches it


def sole_heights(verts: np.ndarray, feet: list[np.ndarray], ground) -> np.ndarray:
    """(F, len(feet)) height of each foot's lowest point above the ground under it (metres).

    ``verts``: world vertices (F, N, 3) of the character; ``feet``: boolean masks of the points of
    each foot; ``ground(xy)``: the surface height under points (N, 2)."""
    out = np.zeros((len(verts), len(feet)))
    for k, mask in enumerate(feet):
        for f, v in enumerate(verts[:, mask]):
            out[f, k] = (v[:, 2] - ground(v[:, :2])).min()
    return out


def sole_slides(verts: np.ndarray, feet: list[np.ndarray], ground) -> np.ndarray:
    """Per foot, the furthest any of its points slides along the ground while touching it: the sum
    of its horizontal moves between consecutive frames at which it touches (within CONTACT),
    over each unbroken stretch of such frames (a step), largest over points and steps."""
    out = []
    for mask in feet:
        v = verts[:, mask]
        touch = np.stack([v[f, :, 2] - ground(v[f, :, :2]) < CONTACT for f in range(len(v))])
        moves = np.linalg.norm(np.diff(v[:, :, :2], axis=0), axis=2)  # (F-1, P)
        both = touch[1:] & touch[:-1]
        run = np.zeros(v.shape[1])
        worst = 0.0
        for f in range(len(moves)):
            run = np.where(both[f], run + moves[f], 0.0)
            worst = max(worst, float(run.max()))
        out.append(worst)
    return np.array(out)
