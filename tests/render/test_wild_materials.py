"""Materials Blender cannot translate, missing textures and stages without lights (issue 12).

The stage has a box whose material is MaterialX only (Blender imports it with no nodes), a box
whose UsdPreviewSurface reads a texture file that does not exist, a ground quad and no light.
The MaterialX box must stay opaque foreground in `render` and `render-video`, lit by the sky and
sun `--light auto` adds, and every problem must reach the user as a warning.
"""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest
from pxr import Gf, Sdf, UsdGeom, UsdShade
from support.analytic import cast
from support.cli import run_cli
from support.scenes import GROUND_HALF, box_matrix
from support.wild import render_and_verify

from lfusd import Dataset
from lfusd.author.rigs import add_rig
from lfusd.author.stage import new_stage
from lfusd.camera import RigSpec

pytestmark = pytest.mark.render

RIG = RigSpec(name="main", rows=2, cols=2, width=32, height=32, baseline=0.1, at=(0.0, -4.0, 1.5), look_at=(0.0, 0.0, 0.4))
FRAMES = 3
MTLX_SIZE, TEX_SIZE = 0.8, 0.6


def mtlx_pose(f: int) -> np.ndarray:
    return box_matrix((-0.6 + 0.1 * (f - 1), 0.0, 0.5), (0.0, 0.0, 20.0))


def tex_pose(f: int) -> np.ndarray:
    return box_matrix((0.7, 0.3, 0.3), (0.0, 0.0, -10.0))


BOXES = {"/World/MtlxBox": (mtlx_pose, MTLX_SIZE), "/World/TexBox": (tex_pose, TEX_SIZE)}


def _box(stage, path: str, size: float, pose) -> UsdGeom.Mesh:
    """A cube mesh of edge ``size`` about its origin, placed by a time-sampled matrix."""
    mesh = UsdGeom.Mesh.Define(stage, path)
    h = size / 2
    mesh.CreatePointsAttr([(x * h, y * h, z * h) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)])
    mesh.CreateFaceVertexCountsAttr([4] * 6)
    mesh.CreateFaceVertexIndicesAttr([0, 2, 3, 1, 4, 5, 7, 6, 0, 1, 5, 4, 2, 6, 7, 3, 0, 4, 6, 2, 1, 3, 7, 5])
    op = mesh.AddTransformOp()
    for f in range(1, FRAMES + 1):
        op.Set(Gf.Matrix4d(*pose(f).T.ravel().tolist()), f)
    return mesh


def write_stage(path, extras: bool = False) -> None:
    """No lights; ``extras``: also a NurbsPatch (Blender skips it) and a reference to a missing file."""
    stage = new_stage(path, 1, FRAMES)
    ground = UsdGeom.Mesh.Define(stage, "/World/Ground")
    g = GROUND_HALF
    ground.CreatePointsAttr([(-g, -g, 0), (g, -g, 0), (g, g, 0), (-g, g, 0)])
    ground.CreateFaceVertexCountsAttr([4])
    ground.CreateFaceVertexIndicesAttr([0, 1, 2, 3])

    mtlx_box = _box(stage, "/World/MtlxBox", MTLX_SIZE, mtlx_pose)
    mat = UsdShade.Material.Define(stage, "/World/Looks/MtlxOnly")
    shader = UsdShade.Shader.Define(stage, "/World/Looks/MtlxOnly/Surface")
    shader.CreateIdAttr("ND_standard_surface_surfaceshader")
    shader.CreateInput("base_color", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(0.8, 0.2, 0.1))
    mat.CreateSurfaceOutput("mtlx").ConnectToSource(shader.ConnectableAPI(), "out")
    UsdShade.MaterialBindingAPI.Apply(mtlx_box.GetPrim()).Bind(mat)

    tex_box = _box(stage, "/World/TexBox", TEX_SIZE, tex_pose)
    mat = UsdShade.Material.Define(stage, "/World/Looks/Textured")
    surface = UsdShade.Shader.Define(stage, "/World/Looks/Textured/Surface")
    surface.CreateIdAttr("UsdPreviewSurface")
    texture = UsdShade.Shader.Define(stage, "/World/Looks/Textured/Albedo")
    texture.CreateIdAttr("UsdUVTexture")
    texture.CreateInput("file", Sdf.ValueTypeNames.Asset).Set("textures/missing_albedo.png")
    texture.CreateOutput("rgb", Sdf.ValueTypeNames.Float3)
    surface.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(texture.ConnectableAPI(), "rgb")
    mat.CreateSurfaceOutput().ConnectToSource(surface.ConnectableAPI(), "surface")
    UsdShade.MaterialBindingAPI.Apply(tex_box.GetPrim()).Bind(mat)

    if extras:
        UsdGeom.NurbsPatch.Define(stage, "/World/Patch")
        stage.DefinePrim("/World/Ref", "Xform").GetReferences().AddReference("./missing_ref.usda")
    add_rig(stage, RIG)
    stage.Save()


@pytest.fixture(scope="module")
def stage(tmp_path_factory):
    path = tmp_path_factory.mktemp("materials") / "materials.usda"
    write_stage(path)
    return path


@pytest.fixture(scope="module")
def video(stage):
    """render-video with the default --light auto, verified; (dataset, what reached stderr)."""
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        ds, _ = render_and_verify(stage, stage.parent / "video")
    return ds, err.getvalue()


def instance_of(ds: Dataset, prim_path: str) -> int:
    return next(i for i, o in ds.objects.items() if o.prim_path == prim_path)


def mtlx_interior(ds: Dataset, frame: int, view) -> tuple[np.ndarray, np.ndarray]:
    """(mask of pixels whose 3x3 neighbourhood all sees the MaterialX box, analytic depth)."""
    boxes = {path: (pose(frame), size) for path, (pose, size) in BOXES.items()}
    depth, hit = cast(ds.intrinsics(view), ds.cam_to_world(frame, view), RIG.width, RIG.height, boxes, GROUND_HALF)
    on = np.pad(hit == "/World/MtlxBox", 1)
    inner = np.ones((RIG.height, RIG.width), bool)
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            inner &= on[dy : dy + RIG.height, dx : dx + RIG.width]
    return inner, depth


def assert_mtlx_box_opaque(ds: Dataset, frames) -> None:
    box = instance_of(ds, "/World/MtlxBox")
    for f in frames:
        for view in ds.views:
            inner, depth = mtlx_interior(ds, f, view)
            assert inner.sum() >= 10, (f, view, inner.sum())  # the rig sees the box well
            inst, z = ds.read(f, view, "instance"), ds.read(f, view, "depth")
            assert (inst[inner] == box).all(), (f, view, np.unique(inst[inner]))
            np.testing.assert_allclose(z[inner], depth[inner], rtol=1e-4, err_msg=f"frame {f} view {view}")


def mtlx_radiance(ds: Dataset, frame: int) -> float:
    """Mean linear RGB over the MaterialX box's interior pixels in every view."""
    values = []
    for view in ds.views:
        inner, _ = mtlx_interior(ds, frame, view)
        values.append(ds.read(frame, view, "rgb_linear")[inner])
    return float(np.concatenate(values).mean())


def test_render_video_keeps_the_materialx_box_opaque_and_warns(video):
    ds, err = video
    assert_mtlx_box_opaque(ds, range(1, FRAMES + 1))
    assert mtlx_radiance(ds, 1) > 0.05  # lit by the sky and sun --light auto added
    assert "material /World/Looks/MtlxOnly has no surface" in err, err
    assert "texture textures/missing_albedo.png is missing" in err, err
    assert err.count("has no lights; lfusd adds a neutral sky and sun") == 1, err
    assert ds.manifest["settings"]["light"] == "auto"


def test_render_keeps_the_materialx_box_opaque_and_light_none_is_dark(capsys, tmp_path, video):
    stage = tmp_path / "extras.usda"
    write_stage(stage, extras=True)  # the same pixels: the extra prims draw nothing
    code, _, err = run_cli(capsys, "render", stage, "-o", tmp_path / "dark", "--samples", "1", "--device", "cpu",
                           "--quiet", "--light", "none")
    assert code == 0, err
    dark = Dataset(tmp_path / "dark")
    assert_mtlx_box_opaque(dark, [1])
    assert dark.manifest["settings"]["light"] == "none"
    assert mtlx_radiance(dark, 1) < 0.2 * mtlx_radiance(video[0], 1)
    assert "has no lights and --light none: it renders black" in err, err
    assert "material /World/Looks/MtlxOnly has no surface" in err, err
    assert "does not render 1 NurbsPatch prim(s) (e.g. /World/Patch)" in err, err
    assert "Blender's USD import: In </World/Ref>: Could not open asset" in err, err
