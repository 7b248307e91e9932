"""``mixed`` by footprint (issue 37.4): a pixel whose square a silhouette or an instance boundary of
the triangles crosses is mixed, however thin the structure. Checked against the wire's projection
computed here in closed form (its eight corners projected, their convex hull against each pixel's
square by separating axes), for the derivation and for verify."""

import numpy as np
import pytest
from support.motion_scenes import Box, Scene, intrinsics, pose, rot

N = 48
WIRE = 0.002  # half width: a 4 mm wire, about a tenth of a pixel here


def wire_scene():
    K = intrinsics(N * 1.05, N, N)
    wall = Box((5, 5, 0.05), {f: pose(t=(0, 0, 6.0)) for f in (1, 2, 3)}, 1, "/World/Wall")
    wire = Box((1.0, WIRE, WIRE), {f: pose(rot((0.1, 0.2, 1), 31.0 + 2 * f), (0.05 * f, 0.1, 3.0)) for f in (1, 2, 3)}, 2, "/World/Wire")
    cams = {f: pose(rot((0, 1, 0), 1.0 * (f - 2)), (0.05 * (f - 2), 0, 0)) for f in (1, 2, 3)}
    return Scene([wall, wire], K, cams, N, N, baseline=0.2)


def _hull(p):
    """Convex hull (counter-clockwise) of 2D points: Andrew's monotone chain."""
    p = sorted(map(tuple, p))

    def half(pts):
        out = []
        for q in pts:
            while len(out) >= 2 and np.cross(np.subtract(out[-1], out[-2]), np.subtract(q, out[-2])) <= 0:
                out.pop()
            out.append(q)
        return out[:-1]

    return np.array(half(p) + half(p[::-1]))


def squares_meeting(poly, H, W, grow=0.0):
    """(H, W) bool: pixel squares (grown by ``grow`` px) that meet the convex polygon, by the
    separating axis theorem: the axes of the square and every edge normal of the polygon."""
    v, u = np.mgrid[0:H, 0:W].astype(float)
    r = 0.5 + grow
    meet = np.ones((H, W), bool)
    meet &= (poly[:, 0].min() <= u + r) & (poly[:, 0].max() >= u - r)
    meet &= (poly[:, 1].min() <= v + r) & (poly[:, 1].max() >= v - r)
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        n = np.array([b[1] - a[1], a[0] - b[0]])
        proj = poly @ n
        c = u * n[0] + v * n[1]
        ext = r * (abs(n[0]) + abs(n[1]))
        meet &= (proj.min() <= c + ext) & (proj.max() >= c - ext)
    return meet


def wire_pixels(sc, frame, grow=0.0):
    box = sc.boxes[1]
    X = (np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * box.half) @ box.poses[frame][:3, :3].T + box.poses[frame][:3, 3]
    u, v, z = sc.project(X, frame)
    assert (z > 0).all()
    return squares_meeting(_hull(np.stack([u, v], -1)), sc.H, sc.W, grow)


def test_every_pixel_a_thin_wire_crosses_is_mixed_and_pixels_away_from_it_are_not():
    sc = wire_scene()
    m = sc.derive(2)["mixed"]
    crossed, near = wire_pixels(sc, 2), wire_pixels(sc, 2, grow=1.0)
    centre = sc.truth(2)["which"] == 1  # pixels whose centre ray meets the wire
    assert crossed.sum() > 40 and centre.sum() < crossed.sum() / 3, "the wire must be thinner than a pixel"
    missed = crossed & ~m
    assert not missed.any(), f"{missed.sum()} of {crossed.sum()} pixels the wire crosses are not mixed"
    assert not (m & ~near).any(), f"{(m & ~near).sum()} pixels more than a pixel away from the wire are mixed"


def test_a_wire_hidden_behind_a_wall_is_not_mixed():
    """The footprint counts only edges not behind what the pixel's corners see: the same wire
    behind an opaque plate marks the plate's outline, never the wire's path behind it."""
    sc = wire_scene()
    plate = Box((0.6, 0.6, 0.01), {f: pose(t=(0.1, 0.1, 2.0)) for f in (1, 2, 3)}, 3, "/World/Plate")
    sc.boxes.append(plate)
    m = sc.derive(2)["mixed"]
    behind = sc.truth(2)["which"] == 1  # the wire (box 1) seen
    v, u = np.mgrid[0:N, 0:N]
    c = sc.project(plate.poses[2][:3, 3][None], 2)
    inside = (np.abs(u - c[0]) < 0.6 * sc.K[0, 0] / 2.0 - 2) & (np.abs(v - c[1]) < 0.6 * sc.K[0, 0] / 2.0 - 2)  # 2 px inside its outline
    assert (wire_pixels(sc, 2) & inside).sum() > 10 and not (behind & inside).any()
    assert not (m & inside).any()


def test_the_edge_table_welds_split_vertices_and_names_boundaries_and_silhouettes():
    """Two quads that share an edge through duplicated points are one surface: no edge between them
    while both face the camera; folded back over the first, their hinge is a silhouette; between two
    instances it is a discontinuity whichever way they face."""
    from lfusd.camera import Camera
    from lfusd.truth.footprint import crossed_by_edges, edge_table

    def quads(x, z):
        # left quad in z = 2 from x = -1 to the hinge at x = 0; the right one from the hinge to (x, z)
        V = np.array([[-1, -1, 2], [0, -1, 2], [0, 1, 2], [-1, 1, 2],
                      [0, -1, 2], [x, -1, z], [x, 1, z], [0, 1, 2]], np.float32)
        return V, np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])

    K = np.array([[20.0, 0, 15.5], [0, 20.0, 15.5], [0, 0, 1]])
    cam = Camera(K, np.eye(4))
    far = np.full(33 * 33, 10.0)  # every corner sees something at 10 m: edges in front of it count
    same = np.zeros(4, np.int64)
    V, T = quads(1.0, 2.5)
    tab = edge_table(V, T)
    assert len(tab["e0"]) == 9 and (tab["t2"] == -1).sum() == 6  # 6 on the boundary; 2 diagonals and the hinge inside
    hinge = (slice(8, 24), slice(15, 17))  # the hinge projects to u = 15.5
    assert not crossed_by_edges(V, T, same, tab, cam, far, 32, 32, 0.01)[hinge].any(), "both quads face the camera: no discontinuity"
    assert crossed_by_edges(V, T, np.array([0, 0, 1, 1]), tab, cam, far, 32, 32, 0.01)[hinge].any(axis=1).all(), \
        "an edge between two instances is a discontinuity"
    V2, T2 = quads(-0.3, 1.0)  # folded back over the left quad: seen from behind
    assert crossed_by_edges(V2, T2, same, edge_table(V2, T2), cam, far, 32, 32, 0.01)[hinge].any(axis=1).all(), \
        "the fold is a silhouette: every pixel along it is crossed"
    assert not crossed_by_edges(V2, T2, same, edge_table(V2, T2), cam, np.full(33 * 33, 1.5), 32, 32, 0.01)[hinge].any(), \
        "an edge behind everything the corners see is hidden"


def test_verify_checks_the_wires_footprint_on_its_own_geometry(tmp_path):
    """Verify decides the footprint again from the stage's triangles: the derived ``mixed`` passes,
    and clearing it on one pixel that only the footprint knows (its four corners all see the wall)
    fails, naming the key."""
    from test_verify import FakeDataset, stage_of

    from lfusd.truth.verify import verify_dataset

    sc = wire_scene()
    stage_of(sc, tmp_path / "s.usda")
    ds = FakeDataset(sc, tmp_path / "s.usda")
    report = verify_dataset(ds)
    assert report.ok, report.failures()
    assert report.certificate()["keys"]["mixed"]["count"] == 3 * N * N  # every pixel of the three frames
    crossed = wire_pixels(sc, 2)
    t = sc.truth(2)
    corners_on_wall = np.ones((N, N), bool)
    v, u = np.mgrid[0:N, 0:N].astype(float)
    for du, dv in ((-0.5, -0.5), (0.5, -0.5), (-0.5, 0.5), (0.5, 0.5)):
        d = np.stack([u + du, v + dv, np.ones_like(u)], -1) @ np.linalg.inv(sc.K).T @ sc.cams[2][:3, :3].T
        corners_on_wall &= sc.cast(np.broadcast_to(sc.cams[2][:3, 3], d.shape), d, 2)[1] == 0
    only = np.argwhere(crossed & corners_on_wall & (t["which"] == 0))
    assert len(only), "the wire must pass between some pixel's corners"
    i, j = only[len(only) // 2]
    ds.data[2]["mixed"][i, j] = False
    report = verify_dataset(ds)
    assert not report.ok and any(line.startswith("mixed") or " mixed" in line for line in report.failures()), report.failures()


@pytest.mark.render
def test_a_rendered_4mm_wire_is_mixed_wherever_it_crosses_a_pixel(tmp_path):
    """Blender, 48x48, 2 frames, 1 sample: a 4 mm wire (a thin box, 0.05 px wide) 4.5 m in front
    of the camera and a wall behind it. Every pixel whose square the wire's projection meets
    (its eight corners from the stage, projected with the dataset's camera) is mixed, no pixel more
    than a pixel away from it is, and verify passes with ``mixed`` checked on every pixel."""
    from pxr import Gf, UsdGeom

    from lfusd import Dataset
    from lfusd.author.labels import set_class_label
    from lfusd.author.rigs import add_rig
    from lfusd.author.stage import new_stage
    from lfusd.camera import Camera, RigSpec, project
    from lfusd.cli import main
    from lfusd.truth.verify import verify_dataset

    stage = new_stage(str(tmp_path / "s.usda"), 1, 2)
    wall = UsdGeom.Cube.Define(stage, "/World/Wall")
    wall.AddTranslateOp().Set(Gf.Vec3d(0, 4, 1.2))
    wall.AddScaleOp().Set(Gf.Vec3f(8, 0.05, 8))  # filling the view: its outline is no discontinuity in it
    set_class_label(wall.GetPrim(), "wall")
    wire = UsdGeom.Cube.Define(stage, "/World/Wire")
    t, r = wire.AddTranslateOp(), wire.AddRotateYOp()
    wire.AddScaleOp().Set(Gf.Vec3f(1.2, WIRE, WIRE))
    for f in (1, 2):
        t.Set(Gf.Vec3d(0.03 * f, 0.0, 1.25), f)
        r.Set(31.0 + 1.5 * f, f)
    set_class_label(wire.GetPrim(), "wire")
    add_rig(stage, RigSpec(name="main", rows=1, cols=1, width=N, height=N, at=(0, -4.5, 1.2), look_at=(0, 0, 1.2)))
    stage.Save()
    assert main(["render-video", str(tmp_path / "s.usda"), "-o", str(tmp_path / "out"), "--samples", "1", "--quiet", "--device", "cpu"]) == 0
    ds = Dataset(tmp_path / "out")
    view = ds.views[0]
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    for frame in (1, 2):
        M = np.array(UsdGeom.Xformable(stage.GetPrimAtPath("/World/Wire")).ComputeLocalToWorldTransform(frame), float)
        X = corners @ M[:3, :3] + M[3, :3]  # USD row vectors
        u, v, z = project(X, Camera(ds.intrinsics(view), ds.cam_to_world(frame, view)))
        assert (z > 0).all()
        hull = _hull(np.stack([u, v], -1))
        crossed, near = squares_meeting(hull, N, N), squares_meeting(hull, N, N, grow=1.0)
        mixed = ds.read(frame, view, "mixed").astype(bool)
        assert crossed.sum() > 25, "the wire must cross the view"
        assert not (crossed & ~mixed).any(), f"frame {frame}: {(crossed & ~mixed).sum()} of {crossed.sum()} pixels the wire crosses are not mixed"
        assert not (mixed & ~near).any(), f"frame {frame}: {(mixed & ~near).sum()} pixels more than a pixel from the wire are mixed"
    report = verify_dataset(ds)
    assert report.ok, report.failures()
    assert report.certificate()["keys"]["mixed"]["count"] == 2 * N * N


def test_verify_band_of_an_edge_reaching_behind_the_camera_stays_near_its_projection():
    """A boundary edge from behind the camera to 5 m in front: clipped at the near plane, its
    projection runs off the image; verify's float band (8 roundoffs of its coordinates at its depth
    in each square) marks the pixels along it, not the whole view (the band at the clipped end's
    depth of 1e-6 m would be huge)."""
    from lfusd.camera import Camera
    from lfusd.truth.footprint import crossed_by_edges, edge_table

    V = np.array([[0.0, 0.0, -1.0], [0.5, 0.2, 5.0], [0.5, 3.0, 5.0]])  # one triangle: every edge a boundary
    T = np.array([[0, 1, 2]])
    K = np.array([[20.0, 0, 15.5], [0, 20.0, 15.5], [0, 0, 1]])
    far = np.full(33 * 33, np.inf)
    tab = edge_table(V, T)
    plain = crossed_by_edges(V, T, np.zeros(1, np.int64), tab, Camera(K, np.eye(4)), far, 32, 32, 0.01)
    band = crossed_by_edges(V, T, np.zeros(1, np.int64), tab, Camera(K, np.eye(4)), far, 32, 32, 0.01, grow=1e-3, ulps=8, fpx=20.0)
    assert plain.any() and (band >= plain).all()
    assert band.sum() <= plain.sum() + 8, f"{band.sum()} px in the band against {plain.sum()} crossed"
