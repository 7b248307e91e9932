"""Authoring helpers shared by the scene templates: meshes, textured materials, lights, objects.

All geometry is UsdGeom.Mesh (boxes, cylinders, tapered shapes) with a face-varying ``st``
primvar, ``subdivisionScheme = none`` and exact extents, so Blender imports exactly the
triangles that lfusd's own geometry (lfusd.author.geometry) sees. Materials are UsdPreviewSurface
with UsdUVTextures reading PNGs by paths relative to the stage file: the colour on diffuseColor,
and detail maps (textures.DETAIL_SUFFIXES) on roughness and normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from pxr import Gf, Sdf, Usd, UsdGeom, UsdLux, UsdShade, Vt

from ..labels import set_class_label
from ..stage import round_values
from ..vocabulary import PHYSICAL_SKY, SKY
from .textures import SPREAD, SPREAD_DEFAULT, ensure_texture

TEXTURE_DIR = "textures"
# Lighting setups a template draws from (Builder.lighting): a sun at a varied elevation and
# azimuth with a sky dome; an overcast sky (dome only); night (a dark sky, the template's street
# lights, spots and lamps turned up); indoor (the room's area and point lights, a dim fill).
LIGHTING_SETUPS = ("sun", "overcast", "night", "indoor")

# Surface finishes by texture name (the rest are matte): glass is see-through and glossy, water
# and chrome reflect. Ground truth is of the first surface a ray meets whatever its finish (see
# CONVENTIONS, "Transparency and reflection").
FINISHES: dict[str, dict[str, float]] = {
    "glass": {"roughness": 0.05, "opacity": 0.3},
    "water": {"roughness": 0.05},
    "chrome": {"roughness": 0.15, "metallic": 1.0},
}


# -- mesh data ----------------------------------------------------------------------------
@dataclass
class MeshData:
    """Polygons in local coordinates with per-face-vertex UVs (in texture repeats)."""

    points: np.ndarray
    counts: list[int]
    indices: list[int]
    uvs: np.ndarray  # (len(indices), 2)


def box(size, centre=(0.0, 0.0, 0.0), tile: float = 1.0) -> MeshData:
    """Axis-aligned box with outward quads; UVs in metres / ``tile`` so textures keep their scale."""
    sx, sy, sz = (float(s) / 2 for s in size)
    c = np.asarray(centre, float)
    pts = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)]) + c
    # Faces as (corner indices, u axis, v axis); corner index = 4*ix + 2*iy + iz; every face is
    # counter-clockwise seen from outside (USD's rightHanded orientation: normals point out).
    faces = [
        ([0, 1, 3, 2], 1, 2),  # -x
        ([4, 6, 7, 5], 1, 2),  # +x
        ([0, 4, 5, 1], 0, 2),  # -y
        ([2, 3, 7, 6], 0, 2),  # +y
        ([0, 2, 6, 4], 0, 1),  # -z
        ([1, 5, 7, 3], 0, 1),  # +z
    ]
    indices, uvs = [], []
    for corners, u, v in faces:
        indices += corners
        uvs += [[pts[k][u] / tile, pts[k][v] / tile] for k in corners]
    return MeshData(pts, [4] * 6, indices, np.array(uvs))


def prism(outline, z0: float, z1: float, tile: float = 1.0) -> MeshData:
    """Vertical prism over a counter-clockwise polygon ``outline`` [(x, y), ...] from z0 to z1."""
    ring = np.asarray(outline, float)
    n = len(ring)
    pts = np.concatenate([np.c_[ring, np.full(n, z0)], np.c_[ring, np.full(n, z1)]])
    counts, indices, uvs = [], [], []
    perim = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.roll(ring, -1, 0) - ring, axis=1))])
    for i in range(n):
        j = (i + 1) % n
        counts.append(4)
        indices += [i, j, n + j, n + i]
        uvs += [[perim[i] / tile, z0 / tile], [perim[i + 1] / tile, z0 / tile], [perim[i + 1] / tile, z1 / tile], [perim[i] / tile, z1 / tile]]
    counts += [n, n]
    indices += list(range(n - 1, -1, -1)) + list(range(n, 2 * n))
    uvs += [[ring[k][0] / tile, ring[k][1] / tile] for k in range(n - 1, -1, -1)]
    uvs += [[ring[k][0] / tile, ring[k][1] / tile] for k in range(n)]
    return MeshData(pts, counts, indices, np.array(uvs))


def cylinder(radius: float, z0: float, z1: float, segments: int = 16, centre=(0.0, 0.0), axis: str = "z",
             radius_top: float | None = None, tile: float = 1.0) -> MeshData:
    """Closed (optionally tapered) cylinder as a polygon mesh; ``axis`` 'x' or 'y' lays it down."""
    r1 = radius if radius_top is None else radius_top
    a = np.arange(segments) * 2 * np.pi / segments
    ring0 = np.c_[radius * np.cos(a), radius * np.sin(a), np.full(segments, z0)]
    ring1 = np.c_[r1 * np.cos(a), r1 * np.sin(a), np.full(segments, z1)]
    pts = np.concatenate([ring0, ring1])
    counts, indices, uvs = [], [], []
    for i in range(segments):
        j = (i + 1) % segments
        counts.append(4)
        indices += [i, j, segments + j, segments + i]
        u0, u1 = i / segments * 2 * np.pi * radius / tile, (i + 1) / segments * 2 * np.pi * radius / tile
        uvs += [[u0, z0 / tile], [u1, z0 / tile], [u1, z1 / tile], [u0, z1 / tile]]
    counts += [segments, segments]
    indices += list(range(segments - 1, -1, -1)) + list(range(segments, 2 * segments))
    uvs += [[pts[k][0] / tile, pts[k][1] / tile] for k in range(segments - 1, -1, -1)]
    uvs += [[pts[k][0] / tile, pts[k][1] / tile] for k in range(segments, 2 * segments)]
    pts = pts + np.array([centre[0], centre[1], 0.0])
    # Proper rotations (determinant +1) keep the outward winding.
    if axis == "x":  # (x, y, z) -> (z, y, -x): the cylinder's axis becomes +x
        pts = np.c_[pts[:, 2], pts[:, 1], -pts[:, 0]]
    elif axis == "y":  # (x, y, z) -> (x, -z, y): the axis becomes -y
        pts = np.c_[pts[:, 0], -pts[:, 2], pts[:, 1]]
    return MeshData(pts, counts, indices, np.array(uvs))


def moved(data: MeshData, offset) -> MeshData:
    """``data`` translated by ``offset``."""
    return MeshData(np.asarray(data.points, float) + np.asarray(offset, float), data.counts, data.indices, data.uvs)


def bowl(radius: float, height: float, segments: int = 16, rings: int = 4, thickness: float = 0.008) -> MeshData:
    """Open bowl (a closed shell: outer and inner surfaces joined at the rim), flat foot at z = 0."""
    t = np.linspace(0.0, 1.0, rings + 1)
    r_out = radius * (0.45 + 0.55 * np.sin(t * np.pi / 2))
    z_out = height * t
    r_in = np.maximum(r_out - thickness, 0.0)
    z_in = np.maximum(z_out, thickness)
    a = np.arange(segments) * 2 * np.pi / segments
    profile = list(zip(r_out, z_out)) + list(zip(r_in[::-1], z_in[::-1]))
    pts = np.array([[r * np.cos(ang), r * np.sin(ang), z] for r, z in profile for ang in a])
    counts, indices, uvs = [], [], []
    n = len(profile)
    for p in range(n - 1):
        for i in range(segments):
            j = (i + 1) % segments
            counts.append(4)
            indices += [p * segments + i, p * segments + j, (p + 1) * segments + j, (p + 1) * segments + i]
            uvs += [[i / segments, p / n], [(i + 1) / segments, p / n], [(i + 1) / segments, (p + 1) / n], [i / segments, (p + 1) / n]]
    # bottom caps: outer foot (facing down) and inner floor (facing up)
    counts += [segments, segments]
    indices += list(range(segments - 1, -1, -1)) + list(range((n - 1) * segments, n * segments))
    uvs += [[0.5 + 0.5 * np.cos(x), 0.5 + 0.5 * np.sin(x)] for x in a[::-1]] + [[0.5 + 0.5 * np.cos(x), 0.5 + 0.5 * np.sin(x)] for x in a]
    return MeshData(pts, counts, indices, np.array(uvs))


def loft(rings, caps=(True, True), tile: float = 1.0) -> MeshData:
    """A closed tube through ``rings`` (each (k, 3), the same k, counter-clockwise seen from the
    last ring's side), closed by triangle fans around each end ring's centroid; UVs: arc length
    around, distance along (metres / ``tile``). Every face is convex when the rings are."""
    rings = [np.asarray(r, float) for r in rings]
    k, n = len(rings[0]), len(rings)
    pts = np.concatenate(rings)
    centres = [rings[0].mean(0), rings[-1].mean(0)]
    arc = [np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.roll(r, -1, 0) - r, axis=1))]) for r in rings]
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm([b.mean(0) - a.mean(0) for a, b in zip(rings, rings[1:])], axis=1))])
    counts, indices, uvs = [], [], []
    for i in range(n - 1):
        for j in range(k):
            jj = (j + 1) % k
            counts.append(4)
            indices += [i * k + j, i * k + jj, (i + 1) * k + jj, (i + 1) * k + j]
            uvs += [[arc[i][j] / tile, along[i] / tile], [arc[i][j + 1] / tile, along[i] / tile],
                    [arc[i + 1][j + 1] / tile, along[i + 1] / tile], [arc[i + 1][j] / tile, along[i + 1] / tile]]
    extra = []
    for end, cap in ((0, caps[0]), (n - 1, caps[1])):
        if not cap:
            continue
        c = len(pts) + len(extra)
        extra.append(centres[0 if end == 0 else 1])
        for j in range(k):
            a, b = end * k + j, end * k + (j + 1) % k
            counts.append(3)
            indices += [c, b, a] if end == 0 else [c, a, b]
            q = rings[end]
            uvs += [[float(p[0]) / tile, float(p[1]) / tile] for p in (extra[-1], q[(j + 1) % k] if end == 0 else q[j], q[j] if end == 0 else q[(j + 1) % k])]
    if extra:
        pts = np.concatenate([pts, np.asarray(extra)])
    return MeshData(pts, counts, indices, np.array(uvs))


def frame_ring(centre, axis, half_u: float, half_v: float, segments: int, power: float = 2.0, ref=None) -> np.ndarray:
    """A superellipse ring (half axes ``half_u``, ``half_v``) around ``centre`` in the plane normal
    to ``axis``, counter-clockwise seen from the tip of ``axis`` (so a :func:`loft` along ``axis``
    faces outward)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    ref = np.asarray(ref if ref is not None else ((0.0, 0.0, 1.0) if abs(axis[2]) < 0.9 else (1.0, 0.0, 0.0)), float)
    u = ref - axis * np.dot(ref, axis)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    t = np.arange(segments) * 2 * np.pi / segments
    c, s = np.cos(t), np.sin(t)
    x = half_u * np.sign(c) * np.abs(c) ** (2.0 / power)
    y = half_v * np.sign(s) * np.abs(s) ** (2.0 / power)
    return np.asarray(centre, float) + np.outer(x, u) + np.outer(y, v)


def rod(a, b, radius: float, segments: int = 8, radius_b: float | None = None, tile: float = 1.0) -> MeshData:
    """A closed (tapered) cylinder from point ``a`` to point ``b``: branches, arms, slanted legs."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    rb = radius if radius_b is None else radius_b
    return loft([frame_ring(a, b - a, radius, radius, segments), frame_ring(b, b - a, rb, rb, segments)], tile=tile)


def blob(centre, radii, rng: np.random.Generator | None = None, segments: int = 8, rings: int = 4,
         bumpiness: float = 0.15, tile: float = 1.0) -> MeshData:
    """A closed, lumpy ellipsoid (foliage clusters, stones): latitude rings scaled by a smooth
    random radial factor from ``rng`` (none: a plain ellipsoid), poles closed by fans."""
    radii = np.asarray(radii, float)
    lat = np.linspace(-np.pi / 2, np.pi / 2, rings + 2)[1:-1]
    lon = np.arange(segments) * 2 * np.pi / segments
    bump = np.ones((len(lat), segments))
    if rng is not None:
        # a few low-frequency waves: lumps without spikes or self-intersections
        for _ in range(3):
            f_lat, f_lon = int(rng.integers(1, 3)), int(rng.integers(1, 4))
            ph = rng.uniform(0, 2 * np.pi, 2)
            bump += bumpiness / 3 * np.sin(f_lat * lat[:, None] * 2 + ph[0]) * np.cos(f_lon * lon[None] + ph[1])
    ring_pts = [np.c_[np.cos(la) * np.cos(lon) * b, np.cos(la) * np.sin(lon) * b, np.full(segments, np.sin(la))] * radii
                for la, b in zip(lat, bump)]
    data = loft([r + np.asarray(centre, float) for r in ring_pts], tile=tile)
    # the caps' centroids are the ring centres; lift them to the poles
    pts = data.points.copy()
    pts[-2] = np.asarray(centre, float) + [0.0, 0.0, -radii[2]]
    pts[-1] = np.asarray(centre, float) + [0.0, 0.0, radii[2]]
    return MeshData(pts, data.counts, data.indices, data.uvs)


def slab(corners, thickness: float, tile: float = 1.0) -> MeshData:
    """A thin plate: the planar convex quad ``corners`` (4, 3) thickened by ``thickness`` along its
    normal (to the side the corners' counter-clockwise order faces: that side stays at
    ``corners``); windows, roofs, pillars, sloped panels."""
    q = np.asarray(corners, float)
    n = np.cross(q[1] - q[0], q[3] - q[0])
    n /= np.linalg.norm(n)
    back = q - n * thickness
    # a hexahedron: loft the back quad to the front quad along the normal
    return loft([back, q], tile=tile)


def extrude_y(outline_xz, y0: float, y1: float, tile: float = 1.0) -> MeshData:
    """A side profile (convex polygon in the x-z plane, counter-clockwise seen from -y) extruded
    from y = ``y0`` to ``y1``: car bodies, hulls' keels, benches' frames."""
    # prism() over (x, -z)... is a reflection; instead prism over (x, z) and turn (a, b, c) ->
    # (a, -c, b), a proper rotation, so the winding stays outward.
    d = prism(outline_xz, -y1, -y0, tile=tile)
    p = d.points
    return MeshData(np.c_[p[:, 0], -p[:, 2], p[:, 1]], d.counts, d.indices, d.uvs)


CREASE_DEG = 50.0  # faces meeting at a sharper angle keep a crisp edge (boxes, 6-sided rods); gentler ones shade smooth


def crease_normals(points, counts, indices, crease_deg: float = CREASE_DEG) -> np.ndarray:
    """Face-varying unit normals (one per face-vertex): at each corner, the area-weighted mean of
    the normals of the faces around its vertex that meet this corner's face within ``crease_deg``.
    Cylinders, wheels and foliage shade round while box edges stay sharp (Blender would shade a
    mesh without normals smooth everywhere, a box's faces included)."""
    pts = np.asarray(points, float)
    counts, indices = np.asarray(counts), np.asarray(indices)
    face = np.repeat(np.arange(len(counts)), counts)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    nxt = np.arange(len(indices)) + 1
    nxt[np.cumsum(counts) - 1] = starts  # each corner's successor within its face
    # Newell's method: twice the area times the unit normal, for any planar or near-planar polygon
    area_n = np.zeros((len(counts), 3))
    np.add.at(area_n, face, np.cross(pts[indices], pts[indices[nxt]]))
    unit = area_n / np.maximum(np.linalg.norm(area_n, axis=1, keepdims=True), 1e-300)
    # pairs of corners sharing a vertex (each corner with itself included)
    order = np.argsort(indices, kind="stable")
    verts = indices[order]
    bounds = np.flatnonzero(np.r_[True, verts[1:] != verts[:-1], True])
    sizes = np.diff(bounds)
    group = np.repeat(np.arange(len(sizes)), sizes)
    rep = sizes[group]  # each sorted corner pairs with every corner of its group
    a = np.repeat(order, rep)
    k = np.arange(rep.sum()) - np.repeat(np.cumsum(rep) - rep, rep)
    b = order[np.repeat(bounds[group], rep) + k]
    keep = np.einsum("ij,ij->i", unit[face[a]], unit[face[b]]) >= np.cos(np.radians(crease_deg))
    out = np.zeros((len(indices), 3))
    np.add.at(out, a[keep], area_n[face[b[keep]]])
    return out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-300)


def chamfer(polygon, distance: float) -> np.ndarray:
    """A convex polygon [(x, y), ...] with every corner cut ``distance`` back along both of its
    edges (at most 0.4 of the shorter one): twice applied, a rounded bevel."""
    p = np.asarray(polygon, float)
    prev, nxt = np.roll(p, 1, 0), np.roll(p, -1, 0)
    out = []
    for a, b, c in zip(prev, p, nxt):
        d = min(distance, 0.4 * np.linalg.norm(a - b), 0.4 * np.linalg.norm(c - b))
        out += [b + (a - b) / np.linalg.norm(a - b) * d, b + (c - b) / np.linalg.norm(c - b) * d]
    return np.array(out)


def merge(*parts: MeshData) -> MeshData:
    """One mesh from several (disjoint) parts."""
    pts, counts, indices, uvs, off = [], [], [], [], 0
    for p in parts:
        pts.append(p.points)
        counts += list(p.counts)
        indices += [i + off for i in p.indices]
        uvs.append(p.uvs)
        off += len(p.points)
    return MeshData(np.concatenate(pts), counts, indices, np.concatenate(uvs))


# -- stage authoring -----------------------------------------------------------------------
@dataclass
class Builder:
    """Authors one scene: materials by texture name (shared), objects, lights."""

    stage: Usd.Stage
    stage_path: Path
    materials: dict[str, UsdShade.Material] = field(default_factory=dict)

    def material(self, texture: str, roughness: float = 0.7, metallic: float = 0.0, opacity: float = 1.0) -> UsdShade.Material:
        """A UsdPreviewSurface material whose diffuse colour is ``textures/<texture>.png``;
        ``opacity`` < 1 makes it see-through (glass, with IOR 1.5; see CONVENTIONS: ground truth
        is of the first surface hit, transparent or not)."""
        key = f"{texture}_{roughness:g}_{metallic:g}" + (f"_o{opacity:g}" if opacity < 1.0 else "")
        key = key.replace(".", "p")
        if key in self.materials:
            return self.materials[key]
        path = Sdf.Path("/World/Looks").AppendChild(key)
        mat = UsdShade.Material.Define(self.stage, path)
        shader = UsdShade.Shader.Define(self.stage, path.AppendChild("Surface"))
        shader.CreateIdAttr("UsdPreviewSurface")
        shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(float(roughness))
        shader.CreateInput("metallic", Sdf.ValueTypeNames.Float).Set(float(metallic))
        if opacity < 1.0:
            shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(float(opacity))
            shader.CreateInput("ior", Sdf.ValueTypeNames.Float).Set(1.5)
        reader = UsdShade.Shader.Define(self.stage, path.AppendChild("StReader"))
        reader.CreateIdAttr("UsdPrimvarReader_float2")
        reader.CreateInput("varname", Sdf.ValueTypeNames.String).Set("st")
        tex = self._texture(path.AppendChild("Diffuse"), texture, reader, "sRGB")
        shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).ConnectToSource(tex.ConnectableAPI(), "rgb")
        # Surface detail (textures.DETAIL_SUFFIXES): roughness varying about the finish's value, and
        # a tangent-space normal map (8-bit, raw: scale 2, bias -1 to [-1, 1], as UsdPreviewSurface asks).
        half = SPREAD.get(texture, SPREAD_DEFAULT) / 2
        scale = min(half, roughness, 1.0 - roughness) / half  # the range stays inside [0, 1]
        rough = self._texture(path.AppendChild("Roughness"), f"{texture}_roughness", reader, "raw", "r",
                              (scale,) * 3 + (1.0,), (roughness - 0.5 * scale,) * 3 + (0.0,))
        shader.GetInput("roughness").ConnectToSource(rough.ConnectableAPI(), "r")
        normal = self._texture(path.AppendChild("Normal"), f"{texture}_normal", reader, "raw", "rgb",
                               (2.0, 2.0, 2.0, 1.0), (-1.0, -1.0, -1.0, 0.0))
        shader.CreateInput("normal", Sdf.ValueTypeNames.Normal3f).ConnectToSource(normal.ConnectableAPI(), "rgb")
        mat.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
        self.materials[key] = mat
        return mat

    def _texture(self, path: Sdf.Path, name: str, reader: UsdShade.Shader, color_space: str, output: str = "rgb",
                 scale=None, bias=None) -> UsdShade.Shader:
        """A UsdUVTexture reading ``textures/<name>.png`` (written here) at the ``st`` of ``reader``."""
        ensure_texture(self.stage_path.parent / TEXTURE_DIR, name)
        tex = UsdShade.Shader.Define(self.stage, path)
        tex.CreateIdAttr("UsdUVTexture")
        tex.CreateInput("file", Sdf.ValueTypeNames.Asset).Set(Sdf.AssetPath(f"./{TEXTURE_DIR}/{name}.png"))
        tex.CreateInput("sourceColorSpace", Sdf.ValueTypeNames.Token).Set(color_space)
        tex.CreateInput("wrapS", Sdf.ValueTypeNames.Token).Set("repeat")
        tex.CreateInput("wrapT", Sdf.ValueTypeNames.Token).Set("repeat")
        if scale is not None:
            tex.CreateInput("scale", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*scale))
            tex.CreateInput("bias", Sdf.ValueTypeNames.Float4).Set(Gf.Vec4f(*bias))
        tex.CreateInput("st", Sdf.ValueTypeNames.Float2).ConnectToSource(reader.ConnectableAPI(), "result")
        tex.CreateOutput(output, Sdf.ValueTypeNames.Float if output == "r" else Sdf.ValueTypeNames.Float3)
        return tex

    def obj(self, path: str, label: str | None, translate=(0.0, 0.0, 0.0), yaw_deg: float = 0.0) -> UsdGeom.Xform:
        """An object Xform (class-labelled when ``label``) at ``translate``, turned ``yaw_deg`` about Z."""
        x = UsdGeom.Xform.Define(self.stage, path)
        x.AddTranslateOp().Set(Gf.Vec3d(*[float(v) for v in translate]))
        if yaw_deg:
            x.AddRotateZOp().Set(float(yaw_deg))
        if label:
            set_class_label(x.GetPrim(), label)
        return x

    def mesh(self, path: str, data: MeshData, texture: str, roughness: float | None = None, metallic: float | None = None,
             opacity: float | None = None) -> UsdGeom.Mesh:
        """A textured polygon mesh at ``path``; the finish (roughness, metallic, opacity) not given
        is the texture's (:data:`FINISHES`, else matte: 0.7, 0, 1)."""
        finish = {"roughness": 0.7, "metallic": 0.0, "opacity": 1.0, **FINISHES.get(texture, {})}
        roughness = finish["roughness"] if roughness is None else roughness
        metallic = finish["metallic"] if metallic is None else metallic
        opacity = finish["opacity"] if opacity is None else opacity
        m = UsdGeom.Mesh.Define(self.stage, path)
        pts = np.asarray(data.points, float)
        # whole arrays through Vt (float64 -> float32 rounds to nearest, as Gf.Vec3f(*p) did per point)
        m.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(pts.astype(np.float32)))
        m.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.asarray(data.counts, np.int32)))
        m.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(data.indices, np.int32)))
        m.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        m.CreateExtentAttr([Gf.Vec3f(*pts.min(0).tolist()), Gf.Vec3f(*pts.max(0).tolist())])
        normals = round_values(crease_normals(pts, data.counts, data.indices), 4)  # 4 places: short files, 1e-4 rad
        m.CreateNormalsAttr(Vt.Vec3fArray.FromNumpy(np.asarray(normals, np.float64).astype(np.float32)))
        m.SetNormalsInterpolation(UsdGeom.Tokens.faceVarying)
        st = UsdGeom.PrimvarsAPI(m).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray, UsdGeom.Tokens.faceVarying)
        st.Set(Vt.Vec2fArray.FromNumpy(np.asarray(data.uvs, float).astype(np.float32)))
        UsdShade.MaterialBindingAPI.Apply(m.GetPrim()).Bind(self.material(texture, roughness, metallic, opacity))
        return m

    # -- lights ----------------------------------------------------------------------------
    def sun(self, azimuth_deg: float, elevation_deg: float, intensity: float, angle: float = 0.53,
            color=(1.0, 0.97, 0.92)) -> UsdLux.DistantLight:
        """A DistantLight shining from ``azimuth``/``elevation`` (degrees; azimuth from +x towards +y)."""
        light = UsdLux.DistantLight.Define(self.stage, "/World/Lights/Sun")
        light.CreateIntensityAttr(float(intensity))
        # normalize = true: intensity is the light's total output, independent of its size or
        # angle (with USD's default, false, Blender imports a 0.53 degree sun as almost black).
        light.CreateNormalizeAttr(True)
        light.CreateAngleAttr(float(angle))
        light.CreateColorAttr(Gf.Vec3f(*color))
        # A DistantLight shines along its local -Z; aim -Z at minus the direction to the sun.
        az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
        to_sun = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        _aim(light, np.zeros(3), -to_sun)
        return light

    def _sphere(self, name: str, radius: float, intensity: float, color) -> UsdLux.SphereLight:
        light = UsdLux.SphereLight.Define(self.stage, f"/World/Lights/{name}")
        light.CreateIntensityAttr(float(intensity))
        light.CreateNormalizeAttr(True)  # see sun(): intensity independent of the light's size
        light.CreateRadiusAttr(float(radius))
        light.CreateColorAttr(Gf.Vec3f(*color))
        return light

    def sphere_light(self, name: str, position, radius: float, intensity: float, color=(1.0, 0.85, 0.65)) -> UsdLux.SphereLight:
        """A point-like SphereLight at ``position`` (Blender: a POINT light of radius ``radius``)."""
        light = self._sphere(name, radius, intensity, color)
        light.AddTranslateOp().Set(Gf.Vec3d(*[float(v) for v in position]))
        return light

    def spot_light(self, name: str, position, target, radius: float, intensity: float, cone_deg: float,
                   softness: float = 0.2, color=(1.0, 0.92, 0.8)) -> UsdLux.SphereLight:
        """A spot: a SphereLight with UsdLux.ShapingAPI, its cone (half-angle ``cone_deg``) about
        local -Z aimed at ``target`` (Blender imports it as a SPOT light)."""
        light = self._sphere(name, radius, intensity, color)
        shaping = UsdLux.ShapingAPI.Apply(light.GetPrim())
        shaping.CreateShapingConeAngleAttr(float(cone_deg))
        shaping.CreateShapingConeSoftnessAttr(float(softness))
        _aim(light, np.asarray(position, float), np.asarray(target, float) - np.asarray(position, float))
        return light

    def rect_light(self, name: str, position, target, width: float, height: float, intensity: float,
                   color=(1.0, 1.0, 1.0)) -> UsdLux.RectLight:
        """A RectLight at ``position`` whose emitting side (local -Z) faces ``target``."""
        light = UsdLux.RectLight.Define(self.stage, f"/World/Lights/{name}")
        light.CreateIntensityAttr(float(intensity))
        # normalize = true: intensity is the light's total output, independent of its size or
        # angle (with USD's default, false, Blender imports a 0.53 degree sun as almost black).
        light.CreateNormalizeAttr(True)
        light.CreateWidthAttr(float(width))
        light.CreateHeightAttr(float(height))
        light.CreateColorAttr(Gf.Vec3f(*color))
        _aim(light, np.asarray(position, float), np.asarray(target, float) - np.asarray(position, float))
        return light

    def disk_light(self, name: str, position, target, radius: float, intensity: float, color=(1.0, 0.9, 0.8)) -> UsdLux.DiskLight:
        """A DiskLight (a spot-like area light) at ``position`` facing ``target``."""
        light = UsdLux.DiskLight.Define(self.stage, f"/World/Lights/{name}")
        light.CreateIntensityAttr(float(intensity))
        # normalize = true: intensity is the light's total output, independent of its size or
        # angle (with USD's default, false, Blender imports a 0.53 degree sun as almost black).
        light.CreateNormalizeAttr(True)
        light.CreateRadiusAttr(float(radius))
        light.CreateColorAttr(Gf.Vec3f(*color))
        _aim(light, np.asarray(position, float), np.asarray(target, float) - np.asarray(position, float))
        return light

    def lighting(self, rng: np.random.Generator, setups: tuple[str, ...]) -> dict:
        """Draw one of ``setups`` (LIGHTING_SETUPS) and author it; return the record that the stage's
        customData keeps (``lfusd:lighting``). Lights the template authored already (lamps, spots,
        area lights under /World/Lights) stay: a night multiplies their intensity by 3 to 5
        (they light the scene), the other setups keep them as they are."""
        setup = str(setups[int(rng.integers(len(setups)))])
        record: dict = {"setup": setup}
        if setup == "sun":
            az, el = float(rng.uniform(0, 360)), float(rng.uniform(10, 75))
            self.sun(az, el, float(rng.uniform(0.8, 1.6)), color=sun_color(el))
            sky = float(rng.uniform(0.3, 0.7))
            self.dome(sky, physical=True)
            record.update(sun_azimuth=az, sun_elevation=el, sky=sky)
        elif setup == "overcast":
            sky = float(rng.uniform(0.9, 1.6))
            self.dome(sky, color=(0.8, 0.82, 0.86))
            record.update(sky=sky)
        elif setup == "night":
            gain = float(rng.uniform(3.0, 5.0))
            for prim in self.stage.GetPrimAtPath("/World/Lights").GetChildren():
                attr = UsdLux.LightAPI(prim).GetIntensityAttr()
                attr.Set(float(attr.Get()) * gain)
            sky = float(rng.uniform(0.02, 0.06))
            self.dome(sky, color=(0.15, 0.2, 0.35))
            record.update(sky=sky, lamp_gain=gain)
        elif setup == "indoor":  # the area and point lights do the work; a dim fill from outside
            sky = float(rng.uniform(0.05, 0.15))
            self.dome(sky, color=(0.9, 0.9, 1.0))
            record.update(sky=sky)
        else:
            raise ValueError(f"unknown lighting setup {setup!r}")
        return {k: (round(v, 3) if isinstance(v, float) else v) for k, v in record.items()}

    def dome(self, intensity: float, color=(0.55, 0.65, 0.85), physical: bool = False) -> UsdLux.DomeLight:
        """A uniform-colour DomeLight (sky fill); ``physical``: marked for Blender's physical sky
        (``lfusd:sky = "physical"``), which lfusd's renderer draws in its place, lit from the
        stage's sun and as bright on average as this dome."""
        light = UsdLux.DomeLight.Define(self.stage, "/World/Lights/Sky")
        if physical:
            light.GetPrim().CreateAttribute(SKY, Sdf.ValueTypeNames.Token, custom=True).Set(PHYSICAL_SKY)
        light.CreateIntensityAttr(float(intensity))
        # normalize = true: intensity is the light's total output, independent of its size or
        # angle (with USD's default, false, Blender imports a 0.53 degree sun as almost black).
        light.CreateNormalizeAttr(True)
        light.CreateColorAttr(Gf.Vec3f(*color))
        return light


# Vertical optical depths of a clear atmosphere at the sun lamp's red, green and blue (about 680,
# 550 and 440 nm): Rayleigh scattering by air (0.043, 0.097, 0.236) plus a thin grey aerosol (0.05).
OPTICAL_DEPTH = (0.093, 0.147, 0.286)


def sun_color(elevation_deg: float) -> tuple[float, float, float]:
    """The colour of direct sunlight at ``elevation_deg`` above the horizon, brightest channel 1:
    transmittance exp(-depth * air mass) along the sun's path (Kasten and Young's air mass), so the
    sun lamp warms towards the horizon as the physical sky beside it does."""
    el = max(float(elevation_deg), 0.0)
    air_mass = 1.0 / (math.sin(math.radians(el)) + 0.50572 * (el + 6.07995) ** -1.6364)
    t = np.exp(-np.asarray(OPTICAL_DEPTH) * air_mass)
    return tuple(float(round(v, 4)) for v in t / t.max())


def _aim(light, position: np.ndarray, direction: np.ndarray) -> None:
    """Place ``light`` at ``position`` with its local -Z along ``direction`` (one matrix op)."""
    d = direction / np.linalg.norm(direction)
    z = -d
    up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.99 else np.array([1.0, 0.0, 0.0])
    x = np.cross(up, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3], m[3, :3] = x, y, z, position  # USD row-vector convention
    light.AddTransformOp().Set(Gf.Matrix4d(*m.ravel().tolist()))
