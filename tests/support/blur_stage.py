"""A stage for motion blur (issue 40): an emissive card parallel to the image plane slides along x at a
constant speed in front of an emissive wall, seen by one camera looking along +y; no lights, so every
pixel's value is its surfaces' emission (no shading noise). Its image speed is closed-form."""

from __future__ import annotations

from pxr import Gf, Sdf, UsdGeom, UsdShade

from lfusd.author.rigs import add_rig
from lfusd.author.stage import new_stage
from lfusd.camera import RigSpec

RIG = RigSpec(name="main", rows=1, cols=1, width=32, height=24, baseline=0.1, focal_length_mm=30.0, at=(0.0, -3.0, 1.0),
              look_at=(0.0, 2.0, 1.0))
CARD_Y, WALL_Y = 0.0, 2.0  # planes y = const; the camera's centre is at y = -3, so planar depths 3 and 5
CARD_HALF = 0.35  # the card: x in x0(t) +- 0.35, z in 1 +- 0.35
SPEED = 0.3  # metres per frame along x: 2.7 px per frame in the image
CARD, WALL = (0.9, 0.3, 0.1), (0.15, 0.2, 0.3)  # linear emission


def card_x(frame: float) -> float:
    return -0.3 + SPEED * (frame - 1)


def _emissive(stage, name: str, colour) -> UsdShade.Material:
    mat = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    shader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/Surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set((0.0, 0.0, 0.0))
    shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(colour)
    shader.CreateInput("useSpecularWorkflow", Sdf.ValueTypeNames.Int).Set(1)
    shader.CreateInput("specularColor", Sdf.ValueTypeNames.Color3f).Set((0.0, 0.0, 0.0))
    mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    return mat


def write_blur_stage(path, frames: int = 3, times=None) -> None:
    """The stage over ``frames`` frames; with ``times``, frame j (from 1) holds the card where it is at time
    ``times[j - 1]`` of the plain stage (sharp renders at sub-frame times through the same pipeline)."""
    times = list(times) if times is not None else list(range(1, frames + 1))
    stage = new_stage(path, 1, len(times))
    wall = UsdGeom.Mesh.Define(stage, "/World/Wall")
    wall.CreatePointsAttr([(-5, WALL_Y, -3), (5, WALL_Y, -3), (5, WALL_Y, 5), (-5, WALL_Y, 5)])
    wall.CreateFaceVertexCountsAttr([4])
    wall.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    UsdShade.MaterialBindingAPI.Apply(wall.GetPrim()).Bind(_emissive(stage, "wall", WALL))
    card = UsdGeom.Mesh.Define(stage, "/World/Card")
    h = CARD_HALF
    card.CreatePointsAttr([(-h, CARD_Y, 1 - h), (h, CARD_Y, 1 - h), (h, CARD_Y, 1 + h), (-h, CARD_Y, 1 + h)])
    card.CreateFaceVertexCountsAttr([4])
    card.CreateFaceVertexIndicesAttr([0, 1, 2, 3])
    op = card.AddTranslateOp()
    for j, t in enumerate(times, start=1):
        op.Set(Gf.Vec3d(card_x(t), 0.0, 0.0), j)
    UsdShade.MaterialBindingAPI.Apply(card.GetPrim()).Bind(_emissive(stage, "card", CARD))
    add_rig(stage, RIG)
    stage.Save()
