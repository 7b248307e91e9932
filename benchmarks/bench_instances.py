"""Object table, verify geometry and object_ids_for on stages of many point instances.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_instances.py [--counts 1000 10000 30000]

Each stage: one PointInstancer of N instances of two tiny box prototypes (8 points each), half of
them inside a nested instancer level (a prototype holding a 2-instance PointInstancer), labelled.
Prints, per N, the seconds of object_table, StageGeometry(stage) + meshes(1) and object_ids_for,
and each time divided by N (constant per-instance time = linear growth).
"""

from __future__ import annotations

import argparse
import time
from types import SimpleNamespace

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, Vt

from lfusd.author.geometry import StageGeometry
from lfusd.author.labels import object_table, set_class_label
from lfusd.author.stage import new_stage
from lfusd.truth.verify import object_ids_for


def _box(stage, path, edge):
    h = edge / 2
    m = UsdGeom.Mesh.Define(stage, path)
    m.CreatePointsAttr([Gf.Vec3f(x * h, y * h, z * h) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)])
    m.CreateFaceVertexCountsAttr([4] * 6)
    m.CreateFaceVertexIndicesAttr([0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5])


def build(n: int) -> Usd.Stage:
    """A stage with one PointInstancer of ``n`` instances (prototype 1 nests 2 more instances)."""
    stage = new_stage(None)
    pi = UsdGeom.PointInstancer.Define(stage, "/World/Scatter")
    set_class_label(pi.GetPrim(), "pebble")
    _box(stage, "/World/Scatter/Protos/Small", 0.02)
    UsdGeom.Xform.Define(stage, "/World/Scatter/Protos/Cluster")
    _box(stage, "/World/Scatter/Protos/Cluster/Core", 0.03)
    inner = UsdGeom.PointInstancer.Define(stage, "/World/Scatter/Protos/Cluster/Bits")
    _box(stage, "/World/Scatter/Protos/Cluster/Bits/Protos/Bit", 0.01)
    inner.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Scatter/Protos/Cluster/Bits/Protos/Bit")])
    inner.CreateProtoIndicesAttr(Vt.IntArray([0, 0]))
    inner.CreatePositionsAttr(Vt.Vec3fArray([Gf.Vec3f(0.02, 0, 0), Gf.Vec3f(-0.02, 0, 0)]))
    pi.CreatePrototypesRel().SetTargets([Sdf.Path("/World/Scatter/Protos/Small"), Sdf.Path("/World/Scatter/Protos/Cluster")])
    pi.CreateProtoIndicesAttr(Vt.IntArray((np.arange(n) % 2).tolist()))
    rng = np.random.default_rng(0)
    pi.CreatePositionsAttr(Vt.Vec3fArray.FromNumpy((rng.random((n, 3)) * [50, 50, 1]).astype(np.float32)))
    return stage


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--counts", type=int, nargs="+", default=[1000, 10000, 30000])
    args = ap.parse_args()
    print(f"{'instances':>9} {'objects':>8} {'meshes':>8} {'object_table s':>15} {'geometry s':>11} {'object_ids_for s':>17}   per instance (us): table / geometry / ids")
    for n in args.counts:
        stage = build(n)
        t0 = time.perf_counter()
        objects, _ = object_table(stage)
        t1 = time.perf_counter()
        meshes = StageGeometry(stage).meshes(1)
        t2 = time.perf_counter()
        ids = object_ids_for([m.prim_path for m in meshes], {o.instance_id: SimpleNamespace(prim_path=o.prim_path) for o in objects})
        t3 = time.perf_counter()
        assert (ids[:-1] > 0).all()
        a, b, c = t1 - t0, t2 - t1, t3 - t2
        print(f"{n:>9} {len(objects):>8} {len(meshes):>8} {a:>15.3f} {b:>11.3f} {c:>17.3f}   {a / n * 1e6:.1f} / {b / n * 1e6:.1f} / {c / n * 1e6:.1f}")


if __name__ == "__main__":
    main()
