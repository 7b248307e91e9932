"""Issue 37 item 1: verify's triangles are Blender's. Measured with bpy 5.0 (a render of the quads
below seen from above; the depth at the quad's centre tells the diagonal): a quad is split along
its corners 0-2 whatever the diagonals' lengths, along 1-3 when 0-2 lies outside it (a concave
quad), and a left-handed mesh's faces are reversed first; faces of 5-9 corners as MEASURED_NGONS."""

import numpy as np
import pytest
from pxr import UsdGeom

from lfusd.author.geometry import triangulate

H = 0.4
BENT = [(-1.2, -1.2, 0), (0.8, -0.8, H), (1.2, 1.2, 0), (-0.8, 0.8, H)]  # 0-2 low and the longer diagonal
ARROW = [(-1, 1, 0), (0, 0.2, 0), (1, 1, 0), (0, -1, 0)]  # reflex at corner 1: the diagonal 0-2 lies outside


def _diagonal(tris):
    """The corner pair the two triangles of one quad share."""
    shared = set(tris[0]) & set(tris[1])
    assert len(shared) == 2
    return tuple(sorted(int(i) for i in shared))


def test_quads_split_as_blender_splits_them():
    q = np.array([4]), np.arange(4)
    assert _diagonal(triangulate(*q)) == (0, 2)
    assert _diagonal(triangulate(*q, np.array(BENT))) == (0, 2)  # not the shorter diagonal 1-3
    assert _diagonal(triangulate(*q, np.array(BENT), left_handed=True)) == (1, 3)
    assert _diagonal(triangulate(np.array([4]), np.array([1, 2, 3, 0]), np.array(BENT))) == (1, 3)  # the loop's first corner
    assert _diagonal(triangulate(*q, np.array(ARROW))) == (1, 3)
    # every triangle of the concave quad lies inside it: the two cover its area exactly
    P = np.array(ARROW)[:, :2]
    area = lambda a, b, c: abs(np.cross(b - a, c - a)) / 2  # noqa: E731
    tris = triangulate(*q, np.array(ARROW))
    poly = 0.5 * abs(sum(np.cross(P[i], P[(i + 1) % 4]) for i in range(4)))
    assert sum(area(*P[t]) for t in tris) == pytest.approx(poly)


def test_faces_keep_their_order_and_mixed_sizes_triangulate():
    counts = np.array([3, 4, 5])
    idx = np.arange(12)
    pts = np.zeros((12, 3))
    pts[3:7] = ARROW
    tris = triangulate(counts, idx, pts)
    assert len(tris) == 1 + 2 + 3
    assert set(tris[1]) | set(tris[2]) == {3, 4, 5, 6} and _diagonal(tris[1:3]) == (4, 6)
    assert tris[3:].min() >= 7  # the pentagon's triangles come last
    left = triangulate(counts, idx, None, left_handed=True)
    assert {tuple(sorted(t)) for t in left[:1]} == {(0, 1, 2)}


# Measured with bpy 5.0 (a top view of regular n-gons with random corner heights, each triangulation
# of the face fitted to the rendered positions, best within 1.3e-6 m, the next 0.02 m off).
MEASURED_NGONS = {
    5: {(0, 1, 4), (1, 2, 3), (1, 3, 4)},
    6: {(0, 1, 5), (1, 2, 3), (1, 3, 5), (3, 4, 5)},
    7: {(0, 1, 6), (1, 2, 3), (1, 3, 5), (1, 5, 6), (3, 4, 5)},
    8: {(0, 1, 7), (1, 2, 3), (1, 3, 7), (3, 4, 5), (3, 5, 7), (5, 6, 7)},
    9: {(0, 1, 8), (1, 2, 3), (1, 3, 5), (1, 5, 7), (1, 7, 8), (3, 4, 5), (5, 6, 7)},
}


def _ngon(n, seed=None):
    a = 2 * np.pi * np.arange(n) / n + 0.3
    z = np.random.default_rng(seed if seed is not None else n).uniform(0, 0.4, n)
    return np.stack([np.cos(a), np.sin(a), z], 1)


@pytest.mark.parametrize("n", sorted(MEASURED_NGONS))
def test_ngons_split_as_blender_splits_them(n):
    tris = triangulate(np.array([n]), np.arange(n), _ngon(n))
    assert {tuple(sorted(int(i) for i in t)) for t in tris} == MEASURED_NGONS[n]
    # the same face upside down (its normal along -z) and with its corners numbered from 3 on
    flipped = _ngon(n) * (1, -1, -1)
    assert {tuple(sorted(int(i) for i in t)) for t in triangulate(np.array([n]), np.arange(n)[::-1], flipped[::-1])} \
        == {tuple(sorted(n - 1 - i for i in t)) for t in MEASURED_NGONS[n]}


def test_a_concave_ngon_is_covered_exactly():
    """An L-shaped hexagon: every triangle lies inside it (ears with a corner inside are passed over)."""
    L = np.array([(0, 0, 0), (2, 0, 0), (2, 1, 0), (1, 1, 0), (1, 2, 0), (0, 2, 0)], float)
    for start in range(6):
        order = np.roll(np.arange(6), -start)
        tris = triangulate(np.array([6]), order, L)
        area = sum(abs(np.cross(L[b] - L[a], L[c] - L[a])[2]) / 2 for a, b, c in tris)
        assert area == pytest.approx(3.0), start


@pytest.mark.render
def test_verify_passes_on_blender_renders_of_bent_concave_and_left_handed_quads(tmp_path):
    """A still render (64x24, 1 sample) of the measured quads: verify's depth and instance agree
    on every pixel (with a fan triangulation the notch of the arrow and the left-handed bent quad
    fail)."""
    from lfusd import Dataset
    from lfusd.author.labels import set_class_label
    from lfusd.author.rigs import add_rig
    from lfusd.author.stage import new_stage
    from lfusd.camera import RigSpec
    from lfusd.cli import main
    from lfusd.truth.verify import verify_dataset

    stage = new_stage(str(tmp_path / "s.usda"), 1, 1)
    shapes = (("Bent", BENT, "rightHanded"), ("Left", BENT, "leftHanded"), ("Arrow", ARROW, "rightHanded"), ("Hepta", _ngon(7), "rightHanded"))
    for k, (name, pts, orient) in enumerate(shapes):
        m = UsdGeom.Mesh.Define(stage, f"/World/{name}")
        m.CreatePointsAttr([(x + 2.6 * (k - 1.5), y, z) for x, y, z in pts])
        m.CreateFaceVertexCountsAttr([len(pts)])
        m.CreateFaceVertexIndicesAttr(list(range(len(pts))))
        m.CreateSubdivisionSchemeAttr("none")
        m.CreateOrientationAttr(orient)
        set_class_label(m.GetPrim(), name.lower())
    floor = UsdGeom.Mesh.Define(stage, "/World/Floor")
    floor.CreatePointsAttr([(-7, -3, -1), (7, -3, -1), (7, 3, -1), (-7, 3, -1)])
    floor.CreateFaceVertexCountsAttr([4])
    floor.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    floor.CreateSubdivisionSchemeAttr("none")
    set_class_label(floor.GetPrim(), "floor")
    add_rig(stage, RigSpec(name="main", rows=1, cols=1, width=80, height=24, focal_length_mm=18.0, at=(0, 0, 6), look_at=(0, 0, 0)))
    stage.Save()
    assert main(["render", str(tmp_path / "s.usda"), "-o", str(tmp_path / "out"), "--samples", "1", "--quiet", "--device", "cpu"]) == 0
    report = verify_dataset(Dataset(tmp_path / "out"))
    assert report.ok, report.failures()
    rows = {(r.key, r.label): r for r in report.rows}
    for label in ("bent", "left", "arrow", "hepta"):
        assert rows[("depth", label)].count > 10, label
