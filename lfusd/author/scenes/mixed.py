"""Mixed outdoor scene: a grass park crossed by a road, a pond with a boat, houses, parked cars,
trees, benches and people; sun, sky, a street lamp and a rect light over a house door."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import GAP, Scene, Site, template
from . import objects as kit
from .build import box

S = 25.0  # half size of the square scene


@dataclass(frozen=True)
class MixedSite(Site):
    road: tuple[float, float]  # the road band (y0, y1)
    pond: tuple[tuple[float, float], tuple[float, float]]  # the pond's (x0, y0), (x1, y1)
    level: float  # the pond's water surface height
    north: tuple[tuple[float, float], tuple[float, float]]  # the park north of the road


@template("mixed", seed_key=3, labels={"road", "grass", "water", "building", "car", "tree", "person"},
          movers={"person", "car", "boat"})
def mixed(scene: Scene) -> MixedSite:
    rng, b = scene.rng, scene.builder
    scene.bounds = ((-S, -S), (S, S))
    ry0, ry1 = -S + 6.0, -S + 6.0 + float(rng.uniform(6.0, 8.0))  # road band (y)
    px0, px1 = float(rng.uniform(-12, -4)), 0.0  # pond (x, y) box, north of the road
    px1 = px0 + float(rng.uniform(8, 12))
    py0 = ry1 + float(rng.uniform(4, 7))
    py1 = py0 + float(rng.uniform(7, 10))
    level = -0.3

    scene.add("/World/Road", "road", [("surface", box((2 * S, ry1 - ry0, 0.3), (0, (ry0 + ry1) / 2, -0.15), tile=4.0), "asphalt")], track=False)
    # Grass tiles around the pond (disjoint boxes), the pond water between them.
    tiles = [("S", (-S, -S), (S, ry0)), ("Mid", (-S, ry1), (S, py0)), ("N", (-S, py1), (S, S)),
             ("W", (-S, py0), (px0, py1)), ("E", (px1, py0), (S, py1))]
    for name, (x0, y0), (x1, y1) in tiles:
        scene.add(f"/World/Grass_{name}", "grass", [("surface", box((x1 - x0, y1 - y0, 2.0), ((x0 + x1) / 2, (y0 + y1) / 2, -1.0), tile=3.0), "grass")], track=False)
    scene.add("/World/Pond", "water", [("surface", box((px1 - px0, py1 - py0, 2.0 + level), ((px0 + px1) / 2, (py0 + py1) / 2, (level - 2.0) / 2), tile=3.0), "water")], track=False)

    parts, draft = kit.boat(rng)
    pose = scene.place(parts, ((px0 + 0.5, py0 + 0.5), (px1 - 0.5, py1 - 0.5)), level - draft, margin=0.5)
    if pose:
        scene.add(scene.name("Boat"), "boat", parts, pose[0], pose[1])

    north = ((-S + 1, ry1 + 1.0), (S - 1, S - 1))
    for _ in range(int(rng.integers(2, 4))):
        w, d = float(rng.uniform(6, 10)), float(rng.uniform(6, 9))
        parts, _ = kit.building(rng, w, d)
        pose = scene.place(parts, north, GAP, yaw_choices=[0.0, 90.0], margin=1.5)
        if pose and not _overlaps(pose, parts, (px0 - 1, py0 - 1), (px1 + 1, py1 + 1)):
            scene.add(scene.name("House"), "building", parts, pose[0], pose[1])
    for _ in range(int(rng.integers(2, 5))):
        parts = scene.draw("car", kit.car)
        pose = scene.place(parts, ((-S + 2, ry0 + 0.3), (S - 2, ry1 - 0.3)), GAP, yaw_choices=[0.0, 180.0], margin=0.8)
        if pose:
            scene.add(scene.name("Car"), "car", parts, pose[0], pose[1])
    for kind, n, label in (("tree", (3, 8), "tree"), ("bench", (1, 4), "bench"), ("litter_bin", (1, 3), "bin"),
                           ("person", (3, 7), "person")):
        for _ in range(int(rng.integers(*n))):
            parts = scene.draw(label, getattr(kit, kind))
            region = north if kind != "person" or rng.random() < 0.6 else ((-S + 2, ry0 + 0.3), (S - 2, ry1 - 0.3))
            pose = scene.place(parts, region, GAP, margin=0.3)
            if pose and not _overlaps(pose, parts, (px0 - 0.3, py0 - 0.3), (px1 + 0.3, py1 + 0.3)):
                scene.add(scene.name(label.capitalize()), label, parts, pose[0], pose[1])

    b.sphere_light("Lamp", (float(rng.uniform(-10, 10)), ry1 + 0.5, 4.5), 0.15, float(rng.uniform(150, 400)))
    b.rect_light("Porch", (px1 + 3.0, py1 + 3.0, 3.0), (px1 + 3.0, py1 + 3.0, 0.0), 0.6, 0.6, float(rng.uniform(50, 150)))
    scene.lighting = b.lighting(rng, ("sun", "sun", "overcast", "night"))

    def rig_position(r):
        return (r.uniform(-S + 5, S - 5), r.uniform(ry0 + 1.0, py0 - 0.5), r.uniform(1.5, 3.0))

    def look_at(r):
        return ((px0 + px1) / 2 + r.uniform(-8, 8), (py0 + py1) / 2 + r.uniform(-6, 2), r.uniform(0.0, 1.5))

    return MixedSite(rig_position, look_at, (ry0, ry1), ((px0, py0), (px1, py1)), level, north)


@mixed.dynamic
def _animate(ctx, site: MixedSite) -> None:
    from .dynamic import boats, loop_beside, traffic

    (ry0, ry1), ((px0, py0), (px1, py1)), level = site.road, site.pond, site.level
    rng = ctx.rng
    mid = (ry0 + ry1) / 2
    traffic(ctx, mid - 1.6, 1, -S, S, int(rng.integers(1, 3)))
    if rng.random() < 0.5:
        traffic(ctx, mid + 1.6, -1, -S, S, 1)
    boats(ctx, level, px0 + 0.3, px1 - 0.3, py0 + 0.3, py1 - 0.3, speeds=(0.05, 0.2))
    # keep walkers off the pond (the person rule refuses water; this keeps paths from trying)
    ctx.occ.boxes.append(("pond", np.array([px0 - 0.3, py0 - 0.3, -5.0]), np.array([px1 + 0.3, py1 + 0.3, 5.0])))
    (nx0, ny0), (nx1, ny1) = site.north

    def spot(r):  # a loop on the grass north of the road (traffic or the pond behind it), beside a bench or bin, else a tree or house
        region = ((nx0 + 3, ny0 + 1.5), (nx1 - 3, min(ny1 - 3, py1 + 4)))
        centre = (float(r.uniform(region[0][0], region[1][0])), float(r.uniform(region[0][1], region[1][1])))
        heading, length, width = float(r.choice([0.0, 90.0])), float(r.uniform(1.2, 2.0)), float(r.uniform(0.4, 0.7))
        # just clear of a prop (a rig behind it has a near foreground the performer passes behind): a bench or
        # bin (small enough for a rig near the loop to look past), else a tree or a house
        # a bin first half the time: the smallest prop, so a rig behind it stands nearest the loop; by a small
        # prop, anywhere on the north grass
        wide = ((nx0 + 3, ny0 + 1.5), (nx1 - 3, ny1 - 3))
        near = loop_beside(ctx, r, ("bin",), wide, length, width, props=site.north) if r.random() < 0.5 else None
        if near is None:
            near = loop_beside(ctx, r, ("bench", "bin"), wide, length, width, props=site.north)
        if near is None:
            near = loop_beside(ctx, r, ("tree", "building"), region, length, width)
        if near is not None:  # loop_beside keeps the centre inside the region
            centre, heading = (float(near[0][0]), float(near[0][1])), near[1]
        elif r.random() < 0.8:
            return None  # performer() asks again: a spot by a prop is worth several tries
        return (centre, GAP, heading, length, width)

    ctx.spot = spot


def _overlaps(pose, parts, lo, hi) -> bool:
    """True when the posed parts' footprint meets the box lo..hi (x, y)."""
    from . import world_box

    wlo, whi = world_box([d for _, d, _ in parts], pose[0], pose[1])
    return bool(wlo[0] < hi[0] and whi[0] > lo[0] and wlo[1] < hi[1] and whi[1] > lo[1])
