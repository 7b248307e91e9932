"""Things: FlyingThings3D-style training scenes. Procedural shapes and props (or catalogue assets
of their classes) in random orientations, sizes, textures (lfusd.author.scenes.textures, the
random ``pattern_NN`` family among them) and finishes (matte, glossy, metallic; nothing
transparent: no honest masks for it yet) float between the rigs and a textured backdrop; the
dynamic variant flies them on straight paths while they tumble. Random sky, sun and lamps.

The disparity is designed, not found. The rigs stand on the plane y = 0 looking along +y
(parallel, so a surface's planar depth is its y), every surface lies between y = ``near`` and the
backdrop's front at y = ``far``, and the baseline ``b`` is drawn so that the disparity per view
step d = f_px * b / y spans ``D`` pixels at the stage's resolution. A sensor shift of ``k`` px per
view step (``k`` the integer nearest the middle of the span) makes it
HCI's signed disparity d - k, within +-``range_px`` (4 px, as the HCI 4D scenes; 16 px for
``things_large``) and of both signs: an *anchor* shape lies wholly in front of the zero plane
y = f_px * b / k inside every rig's centre view, and the backdrop lies behind it. lfusd renders unshifted
parallel rigs, so the shift is applied to the images: translating view (r, c) by ``k`` times its
grid offset (sx, sy) in pixels is exactly that sensor shift (integer pixels, no resampling), and
a point at disparity d in the rendered views is at d - k in the shifted ones (docs/CONVENTIONS.md's
sign rule). The stage keeps the design as customData ``lfusd:disparity`` (shift_px, range_px,
near_m, far_m, zero_m, baseline_m, width_px) for training code to shift with.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...camera import RigSpec
from ...errors import LfusdError
from .. import movers
from ..vocabulary import DISPARITY
from . import Placed, Scene, Site, is_asset, reference_asset, template
from . import objects as kit
from .build import MeshData, blob, bowl, box, cylinder, prism, rod
from .textures import PATTERNS

LENS = RigSpec()  # generate() authors its rigs with RigSpec's lens
HALF_TAN = LENS.sensor_mm / 2 / LENS.focal_length_mm  # tan of half the horizontal field of view
EYE = 2.0  # m: height of the rigs' plane centre (nothing stands on anything: any height would do)
BACK = 0.4  # m: backdrop thickness
CLEAR = 0.05  # m: free gap kept between objects' bounding spheres
# Textures a thing may wear: the random patterns and every opaque named texture.
TEXTURES = tuple(f"pattern_{i:02d}" for i in range(PATTERNS)) + (
    "asphalt", "paving", "bricks", "grass", "wood", "plaster", "wallpaper", "fabric", "bark", "concrete", "ceramic",
    "dirt", "floor_tiles", "paint_red", "paint_blue", "paint_white", "paint_yellow", "paint_dark", "paint_green",
    "paint_silver", "chrome", "tyre", "books", "metal", "denim")
# Props of the object kit (classes of lfusd.author.vocabulary), each a generator of parts.
PROPS = (("car", kit.car), ("chair", kit.chair), ("table", lambda r: kit.table(r)[0]), ("bench", kit.bench),
         ("bin", kit.litter_bin), ("boat", lambda r: kit.boat(r)[0]), ("lamp", lambda r: kit.floor_lamp(r)[0]),
         ("shelf", kit.shelf), ("cabinet", kit.cabinet), ("bowl", kit.bowl_kit))
# Nothing rests on anything: the support rules of the kit's classes are off in these stages.
RULES = {cls: {"on": []} for cls, _ in PROPS} | {"boat": {"floats_on": []}, "wall": {"on": []}}


@dataclass(frozen=True)
class ThingsSite(Site):
    near: float  # y of the nearest surface allowed (m)
    far: float  # y of the backdrop's front face (m)
    flyers: tuple  # (prim path, position, rotateXYZ degrees, bounding radius) of every object that may fly
    f_px: float


@dataclass
class Thing:
    """An object ready to author: a class label, mesh parts centred on the origin (or a catalogue
    asset, about its own origin) and the radius of a sphere about the origin that holds it."""

    label: str
    parts: list  # [(name, MeshData, texture)] or a catalogue asset's parts (is_asset)
    radius: float


def _shape(rng: np.random.Generator) -> MeshData:
    """A random closed primitive: box, (tapered) cylinder, lumpy blob, convex prism, rod or bowl."""
    kind = int(rng.integers(6))
    if kind == 0:
        return box(rng.uniform(0.2, 1.0, 3))
    if kind == 1:
        h = float(rng.uniform(0.3, 1.0))
        r = float(rng.uniform(0.15, 0.5))
        return cylinder(r, -h / 2, h / 2, segments=int(rng.choice([5, 6, 8, 12, 24])), radius_top=r * float(rng.uniform(0.2, 1.0)))
    if kind == 2:
        return blob((0.0, 0.0, 0.0), rng.uniform(0.2, 0.5, 3), rng, segments=12, rings=6, bumpiness=float(rng.uniform(0.0, 0.3)))
    if kind == 3:
        n = int(rng.integers(3, 9))
        a = np.sort(rng.uniform(0, 2 * np.pi, n))  # points on a circle: a convex polygon, counter-clockwise
        if np.max(np.diff(np.r_[a, a[0] + 2 * np.pi])) > np.pi * 0.9:
            a = np.arange(n) * 2 * np.pi / n
        h = float(rng.uniform(0.1, 0.8))
        return prism(np.c_[0.5 * np.cos(a), 0.5 * np.sin(a)], -h / 2, h / 2)
    if kind == 4:
        length = float(rng.uniform(0.5, 1.0))
        return rod((0.0, 0.0, -length / 2), (0.0, 0.0, length / 2), float(rng.uniform(0.04, 0.2)),
                   segments=int(rng.choice([6, 8, 12])), radius_b=float(rng.uniform(0.02, 0.2)))
    r, h = float(rng.uniform(0.2, 0.5)), float(rng.uniform(0.1, 0.4))
    m = bowl(r, h, thickness=float(rng.uniform(0.01, 0.05)))
    return MeshData(np.asarray(m.points, float) - [0.0, 0.0, h / 2], m.counts, m.indices, m.uvs)


def _fit(parts, radius: float, uv_scale: float) -> list:
    """``parts`` moved so their box centre is the origin and scaled so they fit a sphere of ``radius``."""
    pts = np.concatenate([np.asarray(d.points, float) for _, d, _ in parts])
    centre = (pts.min(0) + pts.max(0)) / 2
    s = radius / max(float(np.linalg.norm(pts - centre, axis=1).max()), 1e-9)
    return [(name, MeshData((np.asarray(d.points, float) - centre) * s, d.counts, d.indices, np.asarray(d.uvs, float) * uv_scale), tex)
            for name, d, tex in parts]


def _finish(rng: np.random.Generator) -> tuple[float, float]:
    """(roughness, metallic) of a matte, glossy or metallic finish."""
    kind = rng.choice(3, p=[0.5, 0.3, 0.2])
    if kind == 0:
        return round(float(rng.uniform(0.5, 0.95)), 2), 0.0
    if kind == 1:
        return round(float(rng.uniform(0.05, 0.3)), 2), 0.0
    return round(float(rng.uniform(0.1, 0.5)), 2), 1.0


def _draw(scene: Scene, radius: float, shape: bool) -> Thing:
    """A random procedural shape (``shape``) or prop (a catalogue asset of its class when the scene has any)."""
    rng = scene.rng
    if shape:
        return Thing("shape", _fit([("body", _shape(rng), "")], radius, float(rng.uniform(0.5, 3.0))), radius)
    label, make = PROPS[int(rng.integers(len(PROPS)))]
    parts = scene.draw(label, make)
    if is_asset(parts):  # a catalogue asset keeps its size and origin (grounded, centred): a sphere about that origin
        lo, hi = np.asarray(parts[0][1].points, float).min(0), np.asarray(parts[0][1].points, float).max(0)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        return Thing(label, parts, float(np.linalg.norm(corners, axis=1).max()))
    return Thing(label, _fit(parts, radius, float(rng.uniform(0.5, 2.0))), radius)


def _author(scene: Scene, thing: Thing, pos, rot) -> str:
    """Author ``thing`` at ``pos`` turned by rotateXYZ ``rot`` (degrees) and track its sphere's box."""
    rng, b = scene.rng, scene.builder
    path = scene.name(thing.label.capitalize())
    x = b.obj(path, thing.label)
    movers.author(x.GetPrim(), movers.RigidMotion(np.array([1]), np.asarray([pos], float), np.asarray([rot], float)))
    if is_asset(thing.parts):
        reference_asset(scene.stage, b.stage_path, path, thing.parts[0][2].asset)
    else:
        for part, data, texture in thing.parts:
            roughness, metallic = _finish(rng)
            # mostly re-textured (props are shapes like any other here); glass always: nothing transparent
            if texture not in TEXTURES or rng.random() < 0.7:
                texture = TEXTURES[int(rng.integers(len(TEXTURES)))]
            b.mesh(f"{path}/{part}", data, texture, roughness=roughness, metallic=metallic)
    p = np.asarray(pos, float)
    scene.placed.append(Placed(path, p - thing.radius, p + thing.radius))
    return path


def _things(scene: Scene, range_px: float) -> ThingsSite:
    rng, b = scene.rng, scene.builder
    width, height = scene.resolution
    f_px = LENS.focal_length_mm / LENS.sensor_mm * width  # RigSpec.focal_px at this width
    tan_x, tan_z = HALF_TAN, HALF_TAN * height / width
    extent = (max(scene.grid) - 1) / 2  # the outermost view's offset from the rig centre, in baselines
    # The disparity span D (px per step) and the depths; k (the shift) rounds by at most 1/2, so
    # D <= 2 * range_px - 1 keeps d - k inside +-range_px.
    span = float(rng.uniform(0.7, 1.0)) * (2 * range_px - 1)
    far_over_near = float(rng.uniform(2.5, 6.0))
    step = span / (f_px * (1.0 - 1.0 / far_over_near))  # b / near
    # the rig's own box (lfusd.author.scenes.add_rigs: half = max(grid) * b / 2 + 0.3) must stay clear of the nearest objects
    if max(scene.grid) * step / 2 >= 0.8:
        raise LfusdError(f"a {scene.grid[0]}x{scene.grid[1]} grid at {width} px across cannot span {span:.0f} px of disparity "
                         "without cameras among the objects; use a larger --resolution or a smaller --grid")
    near = max(2.8, 0.5 / (1 - max(scene.grid) * step / 2))  # m: the rig's box (near * that fraction + 0.3) ends 0.2 m short
    near = float(rng.uniform(near, near * 1.6))
    far = near * far_over_near
    base = step * near
    scene.baseline = base
    fb = f_px * base
    shift = int(round((fb / near + fb / far) / 2))
    zero = fb / shift  # depth of zero disparity after the shift
    jitter = 0.15 * near * tan_x  # how far rigs stand from the rig plane's centre (x and z)
    reach = jitter + extent * base  # the farthest a camera stands from the centre line
    scene.bounds = ((-far * tan_x - reach - 2.0, -3.0), (far * tan_x + reach + 2.0, far + BACK + 1.0))
    scene.near_foreground = False

    # The backdrop: its front face at y = far, covering every view's field of view.
    hx, hz = far * tan_x + reach + 1.0, far * tan_z + reach + 1.0
    wall = [("surface", box((2 * hx, BACK, 2 * hz), (0.0, BACK / 2, 0.0), tile=float(rng.uniform(0.5, 4.0))),
             TEXTURES[int(rng.integers(len(TEXTURES)))])]
    b.obj("/World/Backdrop", "wall", (0.0, far, EYE))
    roughness, _ = _finish(rng)
    b.mesh("/World/Backdrop/surface", wall[0][1], wall[0][2], roughness=max(roughness, 0.4), metallic=0.0)
    scene.placed.append(Placed("/World/Backdrop", np.array([-hx, far, EYE - hz]), np.array([hx, far + BACK, EYE + hz])))

    flyers = []
    # The anchor: a shape wholly nearer than the zero plane and inside the centre view of every rig.
    for _ in range(200):
        y = float(rng.uniform(near, min(zero, near * 1.5)))
        radius = float(rng.uniform(0.15, 0.35)) * y * tan_x
        if y - radius < near or y + radius >= zero:
            continue
        room_x, room_z = (y - radius) * tan_x - jitter - radius, (y - radius) * tan_z - jitter - radius
        if room_x <= 0 or room_z <= 0:
            continue
        pos = (float(rng.uniform(-room_x, room_x)), y, EYE + float(rng.uniform(-room_z, room_z)))
        rot = tuple(float(v) for v in rng.uniform(0, 360, 3))
        flyers.append((_author(scene, _draw(scene, radius, True), pos, rot), pos, rot, radius, True))
        break
    else:
        raise LfusdError(f"found no place for the things template's anchor at {width}x{height}; use a larger --resolution")

    # The others: depth uniform in disparity (each disparity equally common), inside the views or just beyond.
    for _ in range(int(rng.integers(14, 30))):
        for _ in range(20):
            d = float(rng.uniform(fb / (far - BACK), fb / near))
            share = float(rng.uniform(0.08, 0.35))  # its radius over the half width of the view at its depth
            wanted = share * fb / d * tan_x
            thing = _draw(scene, wanted, rng.random() < 0.55)
            # a catalogue asset keeps its size: it goes where it has that share of the view
            y = fb / d if thing.radius == wanted else thing.radius / (share * tan_x)
            radius = thing.radius
            y = min(max(y, near + radius), far - CLEAR - radius)
            if y - radius < near or y + radius > far - CLEAR:
                continue
            pos = np.array([rng.uniform(-1.1, 1.1) * (y * tan_x + reach), y, EYE + rng.uniform(-1.1, 1.1) * (y * tan_z + reach)])
            if scene.free(pos - radius, pos + radius, margin=CLEAR):
                rot = tuple(float(v) for v in rng.uniform(0, 360, 3))
                flyers.append((_author(scene, thing, tuple(float(v) for v in pos), rot), tuple(float(v) for v in pos), rot,
                               radius, False))
                break

    # Lamps behind the rigs (never in view) and the sky; a night makes them the light.
    for i in range(int(rng.integers(1, 4))):
        where = (float(rng.uniform(-3, 3) * near * tan_x), float(rng.uniform(-2.0, -0.5)), EYE + float(rng.uniform(-1, 3)))
        colour = tuple(float(c) for c in np.round(1.0 - 0.4 * rng.random(3), 3))
        b.sphere_light(f"Lamp_{i:02d}", where, 0.2, float(rng.uniform(50, 400)) * near * near / 9, colour)
    scene.lighting = b.lighting(rng, ("sun", "sun", "overcast", "night"))
    scene.stage.GetDefaultPrim().SetCustomDataByKey(DISPARITY, {
        "shift_px": shift, "range_px": float(range_px), "near_m": round(near, 6), "far_m": round(far, 6),
        "zero_m": round(zero, 6), "baseline_m": round(base, 9), "width_px": int(width)})

    last = {}

    def rig_position(r):
        # on the plane y = 0; look_at (drawn next by add_rigs) looks straight along +y from here
        last["at"] = (float(r.uniform(-jitter, jitter)), 0.0, EYE + float(r.uniform(-jitter, jitter)))
        return last["at"]

    def look_at(r):
        x, y, z = last["at"]
        return (x, y + far, z)

    return ThingsSite(rig_position, look_at, near, far, tuple(flyers), f_px)


@template("things", seed_key=4, labels={"shape", "wall"}, movers={"shape"}, rules=RULES)
def things(scene: Scene) -> ThingsSite:
    return _things(scene, 4.0)


@template("things_large", seed_key=5, labels={"shape", "wall"}, movers={"shape"}, rules=RULES)
def things_large(scene: Scene) -> ThingsSite:
    return _things(scene, 16.0)


def _animate(ctx, site: ThingsSite) -> None:
    """Fly every object but the anchor on a straight path while it tumbles: 0.5-8 px per frame at
    its depth, its swept box kept inside the depth band and clear of the others' (else it stays)."""
    scene, rng = ctx.scene, ctx.rng
    first = int(scene.stage.GetStartTimeCode())
    frames = np.arange(first, first + ctx.frames)
    steps = (frames - first).astype(float)[:, None]
    for path, pos, rot, radius, anchor in site.flyers:
        if anchor or ctx.frames < 2:
            continue
        pos, rot = np.asarray(pos, float), np.asarray(rot, float)
        for attempt in range(6):
            direction = rng.normal(size=3)
            direction /= np.linalg.norm(direction)
            px = float(rng.uniform(0.5, 8.0)) / (attempt + 1)
            v = direction * px * pos[1] / site.f_px  # m per frame
            end = pos + v * (ctx.frames - 1)
            lo, hi = np.minimum(pos, end) - radius, np.maximum(pos, end) + radius
            if lo[1] < site.near or hi[1] > site.far - CLEAR or not scene.free(lo, hi, margin=CLEAR, ignore=(path,)):
                continue
            spin = rng.uniform(-6.0, 6.0, 3)  # degrees per frame about each axis
            movers.author(scene.stage.GetPrimAtPath(path), movers.RigidMotion(frames, pos + steps * v, rot + steps * spin))
            ctx.occ.reserve(scene, path, lo, hi)
            ctx.movers.append(path)
            break


things.dynamic(_animate)
things_large.dynamic(_animate)
