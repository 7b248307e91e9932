"""render-video --materials on a stage with glass, a mirror, a lamp and a two-material mesh: the masks
match the bound materials on every pixel, depth_behind equals a closed-form ray cast that skips the
transmissive pane, and lfusd verify passes with the effect on."""

from __future__ import annotations

import numpy as np
import pytest
from support.material_stage import QUADS, TWO_X, TWO_Y, TWO_Z, WALL_Y, write_material_stage

from lfusd import Dataset

pytestmark = pytest.mark.render

# the flags the documented rules give each surface (CONVENTIONS "Camera effects"): glass is smooth
# (roughness 0.05, specular 0.5), so mirror-like as well as transmissive
EXPECTED = {"Wall": (False, False, False), "Glass": (True, True, False), "Mirror": (False, True, False),
            "Lamp": (False, False, True), "TwoLeft": (False, False, False), "TwoRight": (False, True, False)}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    from lfusd.cli import main

    root = tmp_path_factory.mktemp("materials")
    stage = root / "materials.usda"
    write_material_stage(stage)
    out = root / "out"
    assert main(["render-video", str(stage), "-o", str(out), "--samples", "1", "--quiet", "--device", "cpu", "--materials",
                 "--iso", "800", "--verify"]) == 0  # --verify: exit 0 only when lfusd verify passes with the effects on
    return out


def _surfaces(ds: Dataset, view) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed form, per pixel centre: the name index of the first surface, its planar depth and the
    planar depth of the first surface that is not the glass (every surface is a quad in a plane y = c)."""
    K, c2w = ds.intrinsics(view), ds.cam_to_world(1, view)
    h, w = ds.rig.height, ds.rig.width
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    d = np.stack([u, v, np.ones_like(u)], -1) @ (c2w[:3, :3] @ np.linalg.inv(K)).T  # camera-frame z = 1
    C = c2w[:3, 3]
    quads = {"Wall": (WALL_Y, -6.0, 6.0, -4.0, 6.0), **{n: q[:5] for n, q in QUADS.items()},
             "TwoLeft": (TWO_Y, TWO_X[0], TWO_X[1], *TWO_Z), "TwoRight": (TWO_Y, TWO_X[1], TWO_X[2], *TWO_Z)}
    names = list(EXPECTED)
    first = np.full((h, w), -1)
    depth = np.full((h, w), np.inf)
    behind = np.full((h, w), np.inf)
    for i, name in enumerate(names):
        y, x0, x1, z0, z1 = quads[name]
        t = (y - C[1]) / d[..., 1]  # the ray parameter is planar depth
        x, z = C[0] + t * d[..., 0], C[2] + t * d[..., 2]
        hit = (t > 0) & (x >= x0) & (x <= x1) & (z >= z0) & (z <= z1)
        nearer = hit & (t < depth)
        first[nearer], depth[nearer] = i, t[nearer]
        if name != "Glass":
            behind = np.where(hit & (t < behind), t, behind)
    return first, depth, behind


def test_masks_match_the_materials_on_every_pixel(rendered):
    ds = Dataset(rendered)
    names = list(EXPECTED)
    for view in ds.views:
        first, depth, _ = _surfaces(ds, view)
        assert np.allclose(ds.read(1, view, "depth"), depth, rtol=1e-4)  # the glass is the first surface
        for k, key in enumerate(("transmissive", "mirror", "emissive")):
            want = np.array([EXPECTED[n][k] for n in names])[first]
            got = ds.read(1, view, key)
            assert got.dtype == bool and np.array_equal(got, want), (view, key, np.argwhere(got != want)[:5])
        seen = {names[i] for i in np.unique(first)}
        assert seen == set(names), seen  # every surface is in the picture: the test covers each rule


def test_depth_behind_is_the_ray_cast_that_skips_transmissive_surfaces(rendered):
    ds = Dataset(rendered)
    for view in ds.views:
        first, depth, behind = _surfaces(ds, view)
        got = ds.read(1, view, "depth_behind")
        glass = first == list(EXPECTED).index("Glass")
        assert glass.sum() > 20
        assert np.allclose(got[glass], behind[glass], rtol=1e-5)
        assert (got[glass] > ds.read(1, view, "depth")[glass] + 1).all()  # behind the pane: the wall 1.5 m further
        assert np.array_equal(got[~glass], ds.read(1, view, "depth")[~glass])  # elsewhere the first surface itself


def test_preview_shows_the_effects_the_dataset_has(rendered, tmp_path):
    from lfusd.data.formats import read_png
    from lfusd.evaluation.preview import preview

    ds = Dataset(rendered)
    names = {p.name for p in preview(ds, tmp_path / "preview", video=False)}
    assert {"rgb_noisy_0001.png", "materials_0001.png", "depth_behind_0001.png"} <= names, names
    assert not {"blur_0001.png", "coc_0001.png"} & names  # rendered without --shutter and --fstop
    noisy = read_png(tmp_path / "preview" / "rgb_noisy_0001.png")
    assert np.array_equal(noisy, ds.read(1, tuple(ds.rig.centre_view), "rgb_noisy"))
