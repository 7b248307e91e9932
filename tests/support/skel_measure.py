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
