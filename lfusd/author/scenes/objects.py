"""Object kits for the templates: lists of (part name, mesh, texture) in the object's local frame.

Every kit has its lowest point at local z = 0 and faces +x, so a template places it by the
support height alone. Every part is a union of closed, outward-wound meshes whose polygons are
convex (lfusd's own geometry fan-triangulates them as Blender does), so rendered depth can be
checked against ray casts on the stage. Thin structures (chair and table legs, poles, railings,
pillars) are a few centimetres across; see tests/author/test_assets.py for the sizes.
"""

from __future__ import annotations

import numpy as np

from ..human import HumanSpec, body_regions
from .build import MeshData, blob, bowl, box, chamfer, cylinder, loft, merge, moved, rod, slab

PAINTS = ("paint_red", "paint_blue", "paint_white", "paint_yellow", "paint_dark", "paint_green", "paint_silver")

Parts = list[tuple[str, MeshData, str]]

WHEEL_RADIUS = 0.32
TYRE_WIDTH = 0.22
ARCH_GAP = 0.03  # metres between a tyre and the car's body around it


# -- cars ---------------------------------------------------------------------------------------
def _panel(quad, outward, thickness: float) -> MeshData:
    """A slab on the planar quad ``quad`` whose front faces ``outward``, ``thickness`` inwards."""
    q = np.asarray(quad, float)
    n = np.cross(q[1] - q[0], q[3] - q[0])
    if np.dot(n, outward) < 0:
        q = q[::-1]
    return slab(q, thickness)


def wheel(radius: float = WHEEL_RADIUS, width: float = TYRE_WIDTH, segments: int = 16) -> MeshData:
    """A tyre centred on its hub, axle along Y: tread on the rolling surface, a spoked rim on both
    sides (the ``tyre`` texture), so its rotation is visible."""
    d = cylinder(radius, -width / 2, width / 2, segments, axis="y")
    a = np.arange(segments) * 2 * np.pi / segments
    disc = np.c_[0.5 + 0.5 * np.cos(a), 0.5 + 0.5 * np.sin(a)]
    side = []
    for i in range(segments):  # the texture's bottom strip is tread
        u0, u1 = 2.0 * i / segments, 2.0 * (i + 1) / segments
        side += [[u0, 0.005], [u1, 0.005], [u1, 0.035], [u0, 0.035]]
    uvs = np.concatenate([side, disc[::-1], disc])
    return MeshData(d.points, d.counts, d.indices, uvs)


def _car_parts(rng: np.random.Generator):
    """(body parts, hub positions, radius): a profiled body, a greenhouse of pillars, roof and glass,
    seats seen through the windows, lights and bumpers."""
    length, width = float(rng.uniform(3.8, 4.6)), float(rng.uniform(1.7, 1.9))
    paint = PAINTS[int(rng.integers(len(PAINTS)))]
    L, W, r = length, width, WHEEL_RADIUS
    hood, roof_z, belt = float(rng.uniform(0.18, 0.24)), float(rng.uniform(1.38, 1.5)), 0.9
    # Side profile (x, z), counter-clockwise seen from -y, convex: the lower body.
    profile = np.array([(-L / 2 + 0.10, 0.28), (L / 2 - 0.15, 0.28), (L / 2, 0.45), (L / 2 - 0.03, 0.70),
                        (L * hood, 0.92), (-L / 2 + 0.12, 0.95), (-L / 2, 0.78), (-L / 2 + 0.02, 0.40)])
    profile = chamfer(chamfer(profile, 0.06), 0.02)  # bevelled corners, shaded round (build.crease_normals)
    centre = profile.mean(0)

    def section(y, inset):
        p = centre + (profile - centre) * [1 - 2 * inset / L, 1 - 2 * inset / 0.67]
        return np.c_[p[:, 0], np.full(len(p), y), p[:, 1]][::-1]  # counter-clockwise seen from +y

    # The tyres stand 2 cm proud of the body's sides (a tyre cap coplanar with the body would be a
    # surface that spins and one that does not in one plane), and the body keeps ARCH_GAP clear
    # of them: a core between the tyres' inner faces, and, outside it, side panels cut around
    # the wheel arches (parts that move differently never interpenetrate).
    hub_y = W / 2 - TYRE_WIDTH / 2 + 0.02
    hubs = [(f"wheel_{'F' if sx > 0 else 'R'}{'L' if sy > 0 else 'R'}", (sx * L * 0.31, sy * hub_y, r))
            for sx in (-1, 1) for sy in (-1, 1)]
    core_y = hub_y - TYRE_WIDTH / 2 - ARCH_GAP
    body = [loft([section(-core_y, 0.0), section(core_y, 0.0)], tile=2.0)]
    arch = r + ARCH_GAP  # half-width of an arch, and (over 2 r) its height
    cuts = [(None, -L * 0.31 - arch), (-L * 0.31 + arch, L * 0.31 - arch), (L * 0.31 + arch, None)]
    pieces = [clip_x_z(profile, x0, x1, None) for x0, x1 in cuts]
    pieces += [clip_x_z(profile, sx * L * 0.31 - arch, sx * L * 0.31 + arch, 2 * r + ARCH_GAP) for sx in (-1, 1)]
    for piece in pieces:
        c = piece.mean(0)
        extent = piece.max(0) - piece.min(0)

        def side(y, inset, piece=piece, c=c, extent=extent):
            q = c + (piece - c) * (1 - 2 * inset / extent)
            return np.c_[q[:, 0], np.full(len(q), y), q[:, 1]][::-1]

        # Rounded shoulders: the panel shrinks by 4 cm over the outer 5 cm of each side; each panel
        # reaches 1 cm into the core (no coplanar faces).
        for sy in (-1, 1):
            rings = [side(sy * (core_y - 0.01), 0.0), side(sy * (W / 2 - 0.05), 0.0), side(sy * W / 2, 0.04)]
            body.append(loft(rings[::sy], tile=2.0))
    # Greenhouse corners: front/rear at the belt (b) and the roof (t).
    xf0, xf1 = L * hood, L * (hood - 0.2)
    xr0, xr1 = -L * 0.38, -L * 0.28
    wb, wt = W / 2 - 0.06, W / 2 - 0.17
    FB = [(xf0, s * wb, belt) for s in (-1, 1)]
    FT = [(xf1, s * wt, roof_z) for s in (-1, 1)]
    RB = [(xr0, s * wb, belt) for s in (-1, 1)]
    RT = [(xr1, s * wt, roof_z) for s in (-1, 1)]
    roof = _panel([RT[0], FT[0], FT[1], RT[1]], (0, 0, 1), 0.05)
    glass = [_panel([FB[0], FB[1], FT[1], FT[0]], (1, 0, 0.6), 0.008),  # windscreen
             _panel([RB[0], RB[1], RT[1], RT[0]], (-1, 0, 0.6), 0.008)]  # rear window
    glass += [_panel([RB[k], FB[k], FT[k], RT[k]], (0, s, 0), 0.008) for k, s in ((0, -1), (1, 1))]
    # Pillars stand 1 cm proud of the glass they frame (no coplanar faces between materials).
    pillars = []
    for k, s in ((0, -1), (1, 1)):
        out = np.array([0.0, s * 0.012, 0.0])
        mid_b, mid_t = (np.add(FB[k], RB[k]) / 2), (np.add(FT[k], RT[k]) / 2)
        for a, b in ((FB[k], FT[k]), (RB[k], RT[k]), (mid_b, mid_t)):
            pillars.append(rod(np.add(a, out) - [0, 0, 0.03], np.add(b, out), 0.035, 6))
    seats = merge(box((0.14, W - 0.45, 0.62), (xf1 - 0.1, 0.0, belt + 0.2)), box((0.14, W - 0.45, 0.55), (xr1 - 0.05, 0.0, belt + 0.15)))
    lights = merge(*[box((0.06, 0.3, 0.1), (L / 2 - 0.035, s * (W / 2 - 0.28), 0.6)) for s in (-1, 1)])
    tail = merge(*[box((0.05, 0.28, 0.1), (-L / 2 - 0.005, s * (W / 2 - 0.25), 0.68)) for s in (-1, 1)])
    trim = merge(box((0.1, W - 0.12, 0.14), (L / 2 - 0.02, 0.0, 0.36)), box((0.1, W - 0.12, 0.14), (-L / 2 + 0.05, 0.0, 0.38)),
                 *[box((0.1, 0.08, 0.07), (xf0 - 0.12, s * (wb + 0.05), belt + 0.12)) for s in (-1, 1)])  # mirrors: within 3 cm of the body
    parts = [("body", merge(*body, roof), paint), ("pillars", merge(*pillars), paint), ("windows", merge(*glass), "glass"),
             ("seats", seats, "fabric"), ("lights", lights, "chrome"), ("taillights", tail, "paint_red"), ("trim", trim, "paint_dark")]
    return parts, hubs, r


def clip_x_z(polygon, x0: float | None, x1: float | None, z0: float | None) -> np.ndarray:
    """The convex polygon (x, z) clipped to x0 <= x <= x1 and z >= z0 (None: no bound); still
    convex, in the same winding."""
    poly = [np.asarray(p, float) for p in polygon]
    for axis, bound, keep_above in ((0, x0, True), (0, x1, False), (1, z0, True)):
        if bound is None:
            continue
        inside = (lambda p: p[axis] >= bound) if keep_above else (lambda p: p[axis] <= bound)
        out = []
        for a, b in zip(poly, poly[1:] + poly[:1]):
            if inside(a):
                out.append(a)
            if inside(a) != inside(b):
                t = (bound - a[axis]) / (b[axis] - a[axis])
                out.append(a + t * (b - a))
        poly = out
    return np.array(poly)


def car(rng: np.random.Generator) -> Parts:
    """A parked car: the moving car's parts with its four wheels as one mesh."""
    parts, hubs, r = _car_parts(rng)
    tyre = wheel(r)
    return parts + [("wheels", merge(*[moved(tyre, hub) for _, hub in hubs]), "tyre")]


def moving_car(rng: np.random.Generator) -> tuple[Parts, list[tuple[str, tuple[float, float, float], MeshData]], float]:
    """A car whose wheels are separate parts: (body parts, [(wheel name, hub in car frame, wheel mesh
    centred on its hub with the axle along Y)], wheel radius). Lowest point at z = 0, facing +x.
    Author each wheel with the ``tyre`` texture (:data:`WHEEL_TEXTURE`)."""
    parts, hubs, r = _car_parts(rng)
    tyre = wheel(r)
    return parts, [(name, hub, tyre) for name, hub in hubs], r


WHEEL_TEXTURE = "tyre"


# -- people (static) -----------------------------------------------------------------------------
_TOPS = ("paint_red", "paint_blue", "paint_white", "paint_yellow", "paint_green", "fabric", "paint_dark")
_BOTTOMS = ("denim", "paint_dark", "paint_silver", "denim")


def person(rng: np.random.Generator) -> Parts:
    """A standing person (the procedural human's body in its rest pose, facing +x): its skin and,
    over it, a closed layer per garment and the hair."""
    spec = HumanSpec(float(rng.uniform(1.55, 1.95)), float(rng.uniform(0.1, 0.9)), look=int(rng.integers(1 << 30)))
    textures = {"skin": "skin", "hair": "hair", "top": _TOPS[int(rng.integers(len(_TOPS)))],
                "bottom": _BOTTOMS[int(rng.integers(len(_BOTTOMS)))], "shoes": "paint_dark"}
    out = []
    for garment, (pts, counts, indices) in body_regions(spec).items():
        p = np.c_[pts[:, 1], -pts[:, 0], pts[:, 2]]  # the human faces +y; turn it to face +x
        uvs = np.c_[p[:, 0] + p[:, 1], p[:, 2]][np.asarray(indices)] * 4.0  # ~25 cm texture repeats
        out.append((garment, MeshData(p, list(counts), list(indices), uvs), textures[garment]))
    return out


# -- vegetation and street furniture ---------------------------------------------------------------
def tree(rng: np.random.Generator) -> Parts:
    """A trunk with branches and clusters of foliage (broadleaf), or a trunk with stacked cones (conifer)."""
    h = float(rng.uniform(3.5, 6.5))
    r0 = float(rng.uniform(0.12, 0.2))
    leaves = "leaves" if rng.random() < 0.5 else "leaves_light"
    if rng.random() < 0.25:  # conifer
        trunk = rod((0, 0, 0), (0, 0, h * 0.5), r0, 10, r0 * 0.6)
        tiers = [cylinder(h * w, h * z0, h * z1, 12, radius_top=0.04) for w, z0, z1 in ((0.26, 0.25, 0.7), (0.2, 0.48, 0.86), (0.13, 0.68, 1.0))]
        return [("trunk", trunk, "bark"), ("crown", merge(*tiers), "leaves")]
    top = h * float(rng.uniform(0.5, 0.6))
    trunk = [rod((0, 0, 0), (0, 0, top), r0, 10, r0 * 0.55)]
    crowns = [blob((0, 0, h - 0.9), (1.0, 1.0, 0.9), rng, tile=1.0)]
    for k in range(int(rng.integers(3, 6))):
        a = 2 * np.pi * (k + float(rng.uniform(-0.2, 0.2))) / 5
        z0 = top * float(rng.uniform(0.7, 0.95))
        reach = float(rng.uniform(0.9, 1.6))
        tip = np.array([reach * np.cos(a), reach * np.sin(a), min(h - 1.2, z0 + float(rng.uniform(0.6, 1.2)))])
        trunk.append(rod((0, 0, z0), tip, 0.055, 6, 0.025))
        rad = float(rng.uniform(0.6, 1.0))
        crowns.append(blob(tip + [0, 0, 0.2], (rad, rad * float(rng.uniform(0.8, 1.1)), rad * 0.8), rng))
    # leaves from their own generator, seeded by the tree's drawn size: the scene's draws (layout,
    # lighting, choreography) stay what they were before trees had leaves
    leaf_rng = np.random.default_rng([round(h * 1e6), round(r0 * 1e6)])
    # the other shade of green than the clusters under them: single leaves stand out of the mass
    return [("trunk", merge(*trunk), "bark"), ("crown", merge(*crowns), leaves),
            ("leaves", merge(*[leaf_cover(c, leaf_rng) for c in crowns]), "leaves_light" if leaves == "leaves" else "leaves")]


LEAF_LENGTH, LEAF_COUNT = 0.22, 80  # per foliage cluster


def leaf_cover(crown: MeshData, rng: np.random.Generator, count: int = LEAF_COUNT, length: float = LEAF_LENGTH) -> MeshData:
    """Leaves over a foliage cluster: thin closed diamonds (6 vertices, 8 triangles) rooted on
    random faces of ``crown`` and leaning out of it at random angles, so its outline breaks up."""
    pts, idx = np.asarray(crown.points, float), np.asarray(crown.indices)
    starts = np.concatenate([[0], np.cumsum(crown.counts)[:-1]])
    centres = np.array([pts[idx[s:s + c]].mean(0) for s, c in zip(starts, crown.counts)])
    middle = pts.mean(0)
    leaves = []
    for f in rng.integers(len(centres), size=count):
        out = centres[f] - middle
        out /= np.linalg.norm(out)
        d = out + rng.normal(0.0, 0.6, 3)  # the leaf's axis: outwards, scattered
        d /= np.linalg.norm(d)
        side = np.cross(d, rng.normal(0.0, 1.0, 3))
        side /= np.linalg.norm(side)
        up = np.cross(side, d)
        root = centres[f] - 0.2 * length * out  # the stalk starts inside the cluster
        rim = [root, root + d * length * 0.5 + side * length * 0.22, root + d * length, root + d * length * 0.5 - side * length * 0.22]
        mid = root + d * length * 0.5
        top, bottom = mid + up * 0.008, mid - up * 0.008
        p = np.round(np.array(rim + [top, bottom]), 4)  # 0.1 mm: shorter files (the leaves are what is written)
        tris = [(0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4), (1, 0, 5), (2, 1, 5), (3, 2, 5), (0, 3, 5)]
        if np.dot(np.cross(p[1] - p[0], p[4] - p[0]), p[4] - mid) < 0:  # keep the winding outward
            tris = [t[::-1] for t in tris]
        flat = [i for t in tris for i in t]
        leaves.append(MeshData(p, [3] * 8, flat, np.round(np.c_[p[flat] @ side, p[flat] @ d] * 2.0, 3)))
    return merge(*leaves)


def street_light(rng: np.random.Generator) -> tuple[Parts, float]:
    """A pole with an arm towards +x; returns (parts, lamp height) — the light sits under the head."""
    h = float(rng.uniform(4.5, 6.0))
    plinth = cylinder(0.12, 0.0, 0.35, 10)
    pole = rod((0, 0, 0.3), (0, 0, h), 0.06, 8, 0.045)
    arm = rod((0.0, 0.0, h - 0.35), (1.0, 0.0, h - 0.12), 0.03, 6)
    head = box((0.5, 0.3, 0.12), (1.1, 0.0, h - 0.16), tile=1.0)
    return [("pole", merge(plinth, pole), "paint_dark"), ("arm", merge(arm, head), "metal")], h - 0.22


def bench(rng: np.random.Generator) -> Parts:
    """Slatted seat and back on two thin metal frames."""
    length = float(rng.uniform(1.5, 2.0))
    slats = [box((0.08, length, 0.035), (x, 0.0, 0.44), tile=0.5) for x in (-0.15, -0.05, 0.05, 0.15)]
    slats += [box((0.03, length, 0.08), (-0.235, 0.0, z), tile=0.5) for z in (0.6, 0.72, 0.84)]
    frame = []
    for y in (-(length / 2 - 0.15), length / 2 - 0.15):
        frame += [box((0.04, 0.04, 0.43), (0.17, y, 0.215)), box((0.04, 0.04, 0.9), (-0.265, y, 0.45)),
                  box((0.46, 0.04, 0.04), (-0.04, y, 0.405))]
    return [("seat", merge(*slats), "wood"), ("frame", merge(*frame), "metal")]


def litter_bin(rng: np.random.Generator) -> Parts:
    """A tapered metal bin with a rim."""
    h = float(rng.uniform(0.8, 1.0))
    body = cylinder(0.22, 0.0, h - 0.04, 14, radius_top=0.25)
    rim = cylinder(0.27, h - 0.06, h, 14)
    return [("body", body, "paint_green" if rng.random() < 0.6 else "paint_dark"), ("rim", rim, "metal")]


def railing(length: float, height: float = 1.0, spacing: float = 1.2, along: str = "x") -> Parts:
    """Posts (5 cm) every ~``spacing`` m from -length/2 to length/2 along x (or y), a top rail and a
    thin mid rail."""
    n = max(2, int(np.ceil(length / spacing)) + 1)
    posts = [box((0.05, 0.05, height - 0.02), (x, 0.0, (height - 0.02) / 2)) for x in np.linspace(-length / 2 + 0.03, length / 2 - 0.03, n)]
    rails = [box((length, 0.06, 0.05), (0.0, 0.0, height)), box((length, 0.03, 0.03), (0.0, 0.0, height * 0.5))]
    parts = [("posts", merge(*posts), "metal"), ("rails", merge(*rails), "paint_dark")]
    if along == "y":  # a quarter turn about z (a proper rotation: windings stay outward)
        parts = [(n_, MeshData(np.c_[-d.points[:, 1], d.points[:, 0], d.points[:, 2]], d.counts, d.indices, d.uvs), t) for n_, d, t in parts]
    return parts


def building(rng: np.random.Generator, width: float, depth: float) -> tuple[Parts, float]:
    floors = int(rng.integers(2, 6))
    h = floors * 3.0
    walls = box((width, depth, h), (0.0, 0.0, h / 2), tile=3.0)
    roof = box((width + 0.3, depth + 0.3, 0.3), (0.0, 0.0, h + 0.15), tile=2.0)
    return [("walls", walls, "bricks"), ("roof", roof, "concrete")], h


def boat(rng: np.random.Generator) -> tuple[Parts, float]:
    """A hull lofted through stations (flat bottom aft, rising to a pointed bow at +x, flared sides,
    sheer), a cabin with a glass windscreen, an outboard motor; returns (parts, draft)."""
    length, width = float(rng.uniform(4.0, 6.5)), float(rng.uniform(1.6, 2.2))
    depth = 0.9
    stations = []
    for t, g, rise, sheer in ((0.0, 0.86, 0.0, 1.0), (0.15, 0.96, 0.0, 1.0), (0.45, 1.0, 0.0, 1.0), (0.7, 0.92, 0.03, 1.02),
                              (0.85, 0.7, 0.13, 1.06), (0.95, 0.36, 0.3, 1.12), (1.0, 0.06, 0.48, 1.18)):
        x = -length / 2 + t * length
        gw = g * width / 2
        b = 0.55 * gw
        zb, top = rise * depth, sheer * depth
        zc = zb + 0.35 * (top - zb)
        gc = b + 0.75 * (gw - b)
        # counter-clockwise seen from +x (the loft's direction): (y, z) pairs
        yz = [(-b, zb), (b, zb), (gc, zc), (gw, top), (-gw, top), (-gc, zc)]
        stations.append(np.array([(x, y, z) for y, z in yz]))
    hull = loft(stations, tile=1.0)
    cx = -length * 0.12
    cabin = box((length * 0.28, width * 0.6, 0.75), (cx, 0.0, depth + 0.355), tile=1.0)
    wx = cx + length * 0.14 + 0.2
    windscreen = _panel([(wx, -width * 0.28, depth - 0.01), (wx, width * 0.28, depth - 0.01),
                         (wx - 0.15, width * 0.28, depth + 0.45), (wx - 0.15, -width * 0.28, depth + 0.45)], (1, 0, 0.3), 0.01)
    motor = box((0.25, 0.3, 0.7), (-length / 2 - 0.12, 0.0, 0.55), tile=0.5)
    paint = PAINTS[int(rng.integers(len(PAINTS)))]
    return ([("hull", hull, paint), ("cabin", cabin, "wood"), ("windscreen", windscreen, "glass"), ("motor", motor, "paint_dark")],
            float(rng.uniform(0.25, 0.45)))


# -- indoor -----------------------------------------------------------------------------------------
def table(rng: np.random.Generator) -> tuple[Parts, float, tuple[float, float]]:
    """A top on four thin round legs. Returns (parts, top height, top size)."""
    lx, ly, h = float(rng.uniform(1.2, 1.8)), float(rng.uniform(0.8, 1.0)), 0.75
    top = box((lx, ly, 0.04), (0.0, 0.0, h - 0.02), tile=1.0)
    top_texture = "glass" if rng.random() < 0.3 else "wood"  # some tables have a glass top
    # legs reach 1 cm into the top: no cap coplanar with its underside
    legs = [rod((sx * (lx / 2 - 0.08), sy * (ly / 2 - 0.08), 0.0), (sx * (lx / 2 - 0.08), sy * (ly / 2 - 0.08), h - 0.03), 0.022, 8)
            for sx in (-1, 1) for sy in (-1, 1)]
    return [("top", top, top_texture), ("legs", merge(*legs), "metal" if rng.random() < 0.5 else "wood")], h, (lx, ly)


def chair(rng: np.random.Generator) -> Parts:
    """A chair whose back is at -x: it faces +x. Legs 2.8 cm across, a slatted back on two posts."""
    s = 0.44
    seat = box((s, s, 0.04), (0.0, 0.0, 0.45), tile=0.5)
    legs = [rod((sx * (s / 2 - 0.03), sy * (s / 2 - 0.03), 0.0), (sx * (s / 2 - 0.03), sy * (s / 2 - 0.03), 0.44), 0.014, 6)
            for sx in (-1, 1) for sy in (-1, 1)]
    posts = [rod((-s / 2 + 0.03, sy * (s / 2 - 0.03), 0.46), (-s / 2 + 0.0, sy * (s / 2 - 0.03), 0.95), 0.014, 6) for sy in (-1, 1)]
    slats = [box((0.02, s - 0.08, 0.06), (-s / 2 + 0.005 + (z - 0.46) * 0.06, 0.0, z)) for z in (0.68, 0.86)]
    fabric = ("fabric", "paint_red", "paint_blue", "wood")[int(rng.integers(4))]
    return [("seat", seat, fabric), ("frame", merge(*legs, *posts, *slats), "wood")]


def bowl_kit(rng: np.random.Generator) -> Parts:
    return [("bowl", bowl(float(rng.uniform(0.08, 0.14)), float(rng.uniform(0.06, 0.1))), "ceramic")]


def floor_lamp(rng: np.random.Generator) -> tuple[Parts, float]:
    """Returns (parts, light height) — the light hangs below the shade."""
    h = float(rng.uniform(1.5, 1.8))
    base = cylinder(0.16, 0.0, 0.03, 12)
    pole = rod((0, 0, 0.02), (0, 0, h - 0.2), 0.012, 6)
    shade = cylinder(0.22, h - 0.25, h, 12, radius_top=0.14)
    return [("stand", merge(base, pole), "paint_dark"), ("shade", shade, "fabric")], h - 0.4


def table_lamp(rng: np.random.Generator) -> Parts:
    """A small lamp for a table top: a base, a thin stem and a shade."""
    h = float(rng.uniform(0.35, 0.5))
    base = cylinder(0.07, 0.0, 0.025, 10)
    stem = rod((0, 0, 0.02), (0, 0, h - 0.12), 0.008, 6)
    shade = cylinder(0.12, h - 0.16, h, 12, radius_top=0.07)
    return [("stand", merge(base, stem), "chrome"), ("shade", shade, "fabric")]


def shelf(rng: np.random.Generator) -> Parts:
    """An open bookcase (back at -x, facing +x): sides, boards, back panel and rows of books."""
    w, d, h = float(rng.uniform(0.8, 1.2)), 0.32, float(rng.uniform(1.2, 2.0))
    t = 0.02
    n = max(2, int(h / 0.38))
    boards_z = np.linspace(0.06, h - t, n + 1)
    frame = [box((d, t, h), (0.0, s * (w / 2 - t / 2), h / 2), tile=1.0) for s in (-1, 1)]
    frame += [box((d - 0.006, w - 2 * t - 0.002, t), (0.003, 0.0, z + t / 2), tile=1.0) for z in boards_z]  # 4 mm into the back
    frame += [box((0.01, w - 2 * t - 0.002, h - 0.002), (-d / 2 + 0.005, 0.0, h / 2), tile=1.0)]
    books = []
    for z0, z1 in zip(boards_z[:-1], boards_z[1:]):
        hb = min(0.3, (z1 - z0) - 0.06)
        fill = float(rng.uniform(0.5, 0.95)) * (w - 2 * t - 0.04)
        y0 = -(w / 2 - t - 0.01) + float(rng.uniform(0.0, (w - 2 * t - 0.02) - fill))
        # the books' box is built at z = 0 so that the texture's one row of spines spans its height
        b = box((0.22, fill, hb), (0.0, 0.0, hb / 2), tile=hb)
        books.append(moved(b, (-d / 2 + 0.13, y0 + fill / 2, z0 + 0.02 + 0.002)))
    return [("frame", merge(*frame), "wood"), ("books", merge(*books), "books")]


def cabinet(rng: np.random.Generator) -> Parts:
    w, d, h = float(rng.uniform(0.8, 1.4)), 0.45, float(rng.uniform(0.8, 1.9))
    return [("carcass", box((d, w, h), (0.0, 0.0, h / 2), tile=1.0), "wood")]


def cabinet_doors(width: float, depth: float, height: float, gap: float = 0.003, thickness: float = 0.02
                  ) -> list[tuple[str, tuple[float, float, float], float, MeshData]]:
    """Two doors on the front (+x) face of a ``cabinet`` carcass: [(name, hinge in cabinet frame,
    opening sign, panel mesh in the hinge frame)]. A door turning by sign * (0..100 degrees) about
    its hinge stays in front of the carcass and clear of the other door."""
    half = width / 2 - gap
    z0, z1 = 0.02, height - 0.02
    left = box((thickness, half, z1 - z0), (thickness / 2, half / 2, (z0 + z1) / 2), tile=1.0)
    right = box((thickness, half, z1 - z0), (thickness / 2, -half / 2, (z0 + z1) / 2), tile=1.0)
    return [("door_L", (depth / 2 + gap, -width / 2, 0.0), -1.0, left),
            ("door_R", (depth / 2 + gap, width / 2, 0.0), 1.0, right)]
