"""Room: a floor with four walls (open to the sky), a table with chairs around it and bowls on
it, a floor lamp (sphere light), cabinets, a person; ceiling rect light, a window sun, a disk
spot and a dome fill."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from pxr import UsdGeom

from .. import movers
from ..labels import object_table
from ..catalogue import placed_size
from . import GAP, Placed, Scene, Site, is_asset, template
from . import objects as kit
from .build import box

H = 2.7  # wall height
T = 0.15  # wall thickness
# Floor kept free for a performer's loop (lfusd.author.scenes.dynamic.performer sweeps the loop
# grown by its 0.6 m person radius): long and short side, metres; a free gap to the chairs lets them slide.
WALK = (2.8, 2.1)
WALK_GAP = 0.45
# The room's lamps were set when Blender shaded every face smooth (walls lit at a slant); with
# crease normals (build.crease_normals) walls face their lights squarely, 0.73 -> 0.87 mean luma
# at these intensities: scaled back so a room is neither dark nor blown out.
LIGHT_GAIN = 0.7


@dataclass(frozen=True)
class RoomSite(Site):
    hx: float  # inner half sizes
    hy: float
    walk: tuple | None = None  # ((x0, y0), (x1, y1)) floor kept free of furniture for a performer's loop


@template("room", seed_key=2, labels={"floor", "wall", "table", "chair", "bowl", "lamp"}, movers={"cabinet"})
def room(scene: Scene) -> RoomSite:
    rng, b = scene.rng, scene.builder
    hx, hy = float(rng.uniform(2.8, 4.0)), float(rng.uniform(2.4, 3.5))  # inner half sizes
    scene.bounds = ((-hx, -hy), (hx, hy))
    floor_tex = "wood" if rng.random() < 0.5 else "floor_tiles"
    wall_tex = "wallpaper" if rng.random() < 0.5 else "plaster"
    scene.add("/World/Floor", "floor", [("surface", box((2 * hx + 2 * T + 0.1, 2 * hy + 2 * T + 0.1, 0.2), (0, 0, -0.1), tile=2.0), floor_tex)], track=False)
    # Walls stand on the floor; the x walls span the corners, the y walls fit between them (no overlap).
    walls = [("N", (2 * hx + 2 * T, T, H), (0, hy + T / 2)), ("S", (2 * hx + 2 * T, T, H), (0, -hy - T / 2)),
             ("E", (T, 2 * hy - 0.01, H), (hx + T / 2, 0)), ("W", (T, 2 * hy - 0.01, H), (-hx - T / 2, 0))]
    for name, size, (x, y) in walls:
        scene.add(f"/World/Wall_{name}", "wall", [("surface", box(size, (0, 0, H / 2), tile=2.5), wall_tex)], (x, y, GAP))

    inner = ((-hx + 0.05, -hy + 0.05), (hx - 0.05, hy - 0.05))
    # Table near the middle; chairs face it; bowls stand on its top.
    drawn = scene.draw("table", kit.table)
    if is_asset(drawn):  # a catalogue table: its top is its highest point; nothing is put on it
        parts, (lx, ly, top_h) = drawn, placed_size(drawn[0][2].asset)
    else:
        parts, top_h, (lx, ly) = drawn
    tx, ty = float(rng.uniform(-hx * 0.3, hx * 0.3)), float(rng.uniform(-hy * 0.3, hy * 0.3))
    yaw = float(rng.choice([0.0, 90.0]))
    table_path = scene.add("/World/Table", "table", parts, (tx, ty, GAP), yaw)
    ex, ey = (lx, ly) if yaw == 0.0 else (ly, lx)
    for k in range(int(rng.integers(2, 5))):
        parts = scene.draw("chair", kit.chair)
        # four sides of the table: the chair faces the table centre
        side = k % 4
        d = [(-1, 0), (1, 0), (0, -1), (0, 1)][side]
        off = (ex / 2 + 0.35, ey / 2 + 0.35)
        cx, cy = tx + d[0] * off[0] + (rng.uniform(-0.2, 0.2) if d[0] == 0 else 0), ty + d[1] * off[1] + (rng.uniform(-0.2, 0.2) if d[1] == 0 else 0)
        cyaw = math.degrees(math.atan2(ty - cy, tx - cx))
        pose = scene.place(parts, ((cx - 0.5, cy - 0.5), (cx + 0.5, cy + 0.5)), GAP, yaw_choices=[cyaw], margin=0.05)
        if pose:
            scene.add(scene.name("Chair"), "chair", parts, pose[0], pose[1])
    # Reserve floor for a performer's loop before the rest of the furniture comes (the room fills up
    # otherwise and no rig finds a walker to watch); dropped again once the room is furnished.
    walk = None
    for _ in range(60):
        wx, wy = WALK if rng.random() < 0.5 else WALK[::-1]
        if wx > 2 * hx - 0.2 or wy > 2 * hy - 0.2:
            continue
        x, y = float(rng.uniform(-hx + 0.1 + wx / 2, hx - 0.1 - wx / 2)), float(rng.uniform(-hy + 0.1 + wy / 2, hy - 0.1 - wy / 2))
        lo, hi = np.array([x - wx / 2, y - wy / 2, 0.0]), np.array([x + wx / 2, y + wy / 2, H])
        if scene.free(lo, hi, margin=WALK_GAP):
            walk = ((float(lo[0]), float(lo[1])), (float(hi[0]), float(hi[1])))
            scene.placed.append(Placed("/World#walk", lo, hi))
            break
    top = ((tx - ex / 2 + 0.05, ty - ey / 2 + 0.05), (tx + ex / 2 - 0.05, ty + ey / 2 - 0.05))
    for _ in range(int(rng.integers(2, 6)) if not is_asset(drawn) else 0):
        parts = kit.bowl_kit(rng)
        pose = scene.place(parts, top, top_h + 2 * GAP, margin=0.05, ignore=(table_path,))
        if pose:
            scene.add(scene.name("Bowl"), "bowl", parts, pose[0], pose[1])

    if rng.random() < 0.6 and not is_asset(drawn):  # a table lamp among the bowls
        parts = kit.table_lamp(rng)
        pose = scene.place(parts, top, top_h + 2 * GAP, margin=0.05, ignore=(table_path,))
        if pose:
            scene.add("/World/TableLamp", "lamp", parts, pose[0], pose[1])

    # Cabinets and bookshelves against the walls (backs to the wall), a floor lamp, a person.
    for k in range(int(rng.integers(2, 5))):
        kind = "cabinet" if k % 2 == 0 else "shelf"
        parts = scene.draw(kind, getattr(kit, kind))
        side = int(rng.integers(4))
        yaw = [0.0, 180.0, 90.0, 270.0][side]
        if side == 0:
            region = ((-hx + 0.02, -hy + 0.3), (-hx + 0.6, hy - 0.3))
        elif side == 1:
            region = ((hx - 0.6, -hy + 0.3), (hx - 0.02, hy - 0.3))
        elif side == 2:
            region = ((-hx + 0.3, -hy + 0.02), (hx - 0.3, -hy + 0.6))
        else:
            region = ((-hx + 0.3, hy - 0.6), (hx - 0.3, hy - 0.02))
        pose = scene.place(parts, region, GAP, yaw_choices=[yaw], margin=0.05, tries=20)
        if pose:
            scene.add(scene.name(kind.capitalize()), kind, parts, pose[0], pose[1])
    parts, light_h = kit.floor_lamp(rng)
    pose = scene.place(parts, inner, GAP, margin=0.2)
    if pose:
        (x, y, z), _ = pose
        scene.add("/World/Lamp", "lamp", parts, (x, y, z), pose[1])
        b.sphere_light("LampBulb", (x + 0.12, y, z + light_h), 0.05, LIGHT_GAIN * float(rng.uniform(20, 60)))
    if rng.random() < 0.7:
        parts = scene.draw("person", kit.person)
        pose = scene.place(parts, inner, GAP, margin=0.25)
        if pose:
            scene.add(scene.name("Person"), "person", parts, pose[0], pose[1])

    scene.placed = [p for p in scene.placed if p.path != "/World#walk"]

    b.rect_light("Ceiling", (0.0, 0.0, H + 0.3), (0.0, 0.0, 0.0), 1.2, 0.6, LIGHT_GAIN * float(rng.uniform(40, 100)))
    b.disk_light("Downlight", (tx + 0.8, ty, H + 0.2), (tx + 0.8, ty, 0.0), 0.15, LIGHT_GAIN * float(rng.uniform(30, 90)))
    b.spot_light("Spot", (tx - 0.5, ty - 0.5, H + 0.2), (tx, ty, top_h), 0.05, LIGHT_GAIN * float(rng.uniform(60, 150)),
                 float(rng.uniform(20, 35)))
    scene.lighting = b.lighting(rng, ("indoor", "indoor", "sun", "night"))
    # indoor scale: objects 1-4 m away, so a small baseline keeps disparities like the street's
    scene.baseline = 0.05
    scene.near_foreground = False

    def rig_position(r):
        return (r.uniform(-hx + 1.0, hx - 1.0), r.uniform(-hy + 1.0, hy - 1.0), r.uniform(1.4, 2.0))

    def look_at(r):
        return (tx + r.uniform(-0.5, 0.5), ty + r.uniform(-0.5, 0.5), top_h + r.uniform(-0.3, 0.3))

    return RoomSite(rig_position, look_at, hx, hy, walk)


@room.dynamic
def _animate(ctx, site: RoomSite) -> None:
    
    hx, hy = site.hx, site.hy
    scene, rng, clip = ctx.scene, ctx.rng, ctx.duration
    objs = object_table(ctx.stage)[0]
    for o in objs:
        if o.label == "cabinet" and clip >= 1.0:
            prim = ctx.stage.GetPrimAtPath(o.prim_path)
            pts = movers._local_points(prim)
            depth, width, height = np.ptp(pts, axis=0)
            pos, yaw = movers.start_pose(prim)
            c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
            corners = np.array([[x, y] for x in (depth / 2, depth / 2 + width / 2 + 0.05) for y in (-width / 2 - 0.05, width / 2 + 0.05)])
            world = corners @ np.array([[c, s], [-s, c]]) + pos[:2]
            lo, hi = np.r_[world.min(0), pos[2]], np.r_[world.max(0), pos[2] + height]
            if not ctx.occ.free(lo, hi, ignore=(o.prim_path,)):
                continue
            for name, hinge, sign, panel in kit.cabinet_doors(width, depth, height):
                # the hinge transform on the panel mesh itself (see lfusd.author.movers.make_wheel for why)
                door = scene.builder.mesh(f"{o.prim_path}/{name}", panel, "wood")
                door.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(tuple(float(v) for v in hinge))
                t_open = float(rng.uniform(0.05, 0.4)) * clip
                dur = float(rng.uniform(0.8, 1.4))
                t_close = t_open + dur + float(rng.uniform(0.5, 2.0))
                movers.swing(ctx.stage, f"{o.prim_path}/{name}", sign * float(rng.uniform(70, 100)), t_open,
                             t_close if t_close + dur < clip else None, dur)
            ctx.occ.boxes.append((o.prim_path + "#doors", lo, hi))
            scene.placed.append(Placed(o.prim_path + "#doors", lo, hi))
            ctx.movers.append(o.prim_path)
    for o in objs:
        if o.label == "chair" and clip >= 1.0 and rng.random() < 0.6:
            prim = ctx.stage.GetPrimAtPath(o.prim_path)
            pos, yaw = movers.start_pose(prim)
            back = -np.array([np.cos(np.radians(yaw)), np.sin(np.radians(yaw))]) * float(rng.uniform(0.2, 0.4))
            box = next(p for p in scene.placed if p.path == o.prim_path)
            lo = np.minimum(box.lo, box.lo + np.r_[back, 0.0])
            hi = np.maximum(box.hi, box.hi + np.r_[back, 0.0])
            inside = lo[0] > -hx + 0.05 and hi[0] < hx - 0.05 and lo[1] > -hy + 0.05 and hi[1] < hy - 0.05
            if inside and ctx.occ.free(lo, hi, ignore=(o.prim_path,)):
                t0, dur = float(rng.uniform(0.05, 0.4)) * clip, float(rng.uniform(0.8, 1.5))
                t_back = t0 + dur + float(rng.uniform(0.5, 2.0))
                movers.slide(ctx.stage, o.prim_path, back, t0, dur, t_back if t_back + dur < clip else None)
                ctx.occ.reserve(scene, o.prim_path, lo, hi)
                ctx.movers.append(o.prim_path)

    def spot(r):  # a small loop: on the reserved floor, else anywhere (performer() keeps it off walls and furniture)
        if site.walk is not None and r.random() < 0.5:
            (x0, y0), (x1, y1) = site.walk
            along_x = x1 - x0 >= y1 - y0
            long, short = (x1 - x0, y1 - y0) if along_x else (y1 - y0, x1 - x0)
            length = float(r.uniform(0.8, min(1.6, long - 1.25)))
            width = float(r.uniform(0.4, min(0.8, short - 1.25)))
            ex, ey = (length, width) if along_x else (width, length)
            cx = float(r.uniform(x0 + ex / 2 + 0.62, x1 - ex / 2 - 0.62))
            cy = float(r.uniform(y0 + ey / 2 + 0.62, y1 - ey / 2 - 0.62))
            return (cx, cy), GAP, 0.0 if along_x else 90.0, length, width
        length, width = float(r.uniform(0.8, 1.6)), float(r.uniform(0.4, 0.8))
        return ((float(r.uniform(-hx + 0.9, hx - 0.9)), float(r.uniform(-hy + 0.9, hy - 0.9))), GAP,
                float(r.choice([0.0, 90.0])), length, width)

    ctx.spot = spot
