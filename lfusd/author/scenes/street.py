"""Street: a road along x with lane markings, raised pavements, grass verges, buildings, parked
cars, street lights (sphere lights), trees and people; sun and sky."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import GAP, Scene, Site, template, world_box
from . import objects as kit
from .build import box, merge

L = 60.0  # street length (x from -L/2 to L/2)


@dataclass(frozen=True)
class StreetSite(Site):
    road_w: float  # half width of the road
    walk_w: float  # pavement width
    curb: float  # pavement height


@template("street", seed_key=0, labels={"road", "sidewalk", "grass", "building", "car", "street_light", "person"},
          movers={"person", "car"})
def street(scene: Scene) -> StreetSite:
    rng, b = scene.rng, scene.builder
    road_w = float(rng.uniform(3.2, 4.2))  # half width
    walk_w = float(rng.uniform(2.5, 3.5))
    curb = 0.15
    verge = 14.0
    scene.bounds = ((-L / 2, -(road_w + walk_w + verge)), (L / 2, road_w + walk_w + verge))

    # Road: top at z = 0, dashed centre line 1 mm above it (part of the road object).
    dashes = [box((3.0, 0.15, 0.002), (x, 0.0, 0.001), tile=1.0) for x in np.arange(-L / 2 + 2.5, L / 2, 6.0)]
    scene.add("/World/Road", "road", [("surface", box((L, 2 * road_w, 0.3), (0, 0, -0.15), tile=4.0), "asphalt"),
                                       ("markings", merge(*dashes), "paint_white")], track=False)
    for side, s in (("N", 1), ("S", -1)):
        yc = s * (road_w + walk_w / 2)
        scene.add(f"/World/Pavement_{side}", "sidewalk", [("surface", box((L, walk_w, 0.45), (0, yc, curb - 0.225), tile=2.0), "paving")], track=False)
        yg = s * (road_w + walk_w + verge / 2)
        scene.add(f"/World/Verge_{side}", "grass", [("surface", box((L, verge, 0.3), (0, yg, -0.15), tile=3.0), "grass")], track=False)

    # Buildings on the verges, set back from the pavement.
    for s in (1, -1):
        x = -L / 2 + 1.0
        while x < L / 2 - 6.0:
            w, d = float(rng.uniform(6.0, 11.0)), float(rng.uniform(6.0, 9.0))
            if x + w > L / 2 - 1.0:
                break
            parts, _ = kit.building(rng, w, d)
            y0 = s * (road_w + walk_w + float(rng.uniform(1.5, 3.0)) + d / 2)
            scene.add(scene.name("Building"), "building", parts, (x + w / 2, y0, GAP))
            x += w + float(rng.uniform(1.0, 4.0))

    # Parked cars near the kerbs, driving lanes kept clear for issue-6 movers.
    for _ in range(int(rng.integers(4, 8))):
        parts = scene.draw("car", kit.car)
        s = 1 if rng.random() < 0.5 else -1
        y0, y1 = sorted((s * (road_w - 0.1), s * (road_w - 2.1)))
        region = ((-L / 2 + 3, y0), (L / 2 - 3, y1))
        pose = scene.place(parts, region, GAP, yaw_choices=[0.0, 180.0], margin=0.6)
        if pose:
            scene.add(scene.name("Car"), "car", parts, pose[0], pose[1])

    # Street lights along the pavement edge, arm over the road.
    lx = -L / 2 + float(rng.uniform(3, 8))
    k = 0
    while lx < L / 2 - 3:
        s = 1 if k % 2 == 0 else -1
        parts, lamp_h = kit.street_light(rng)
        y = s * (road_w + 0.5)
        yaw = 270.0 if s > 0 else 90.0
        (lo, hi) = world_box([d for _, d, _ in parts], (lx, y, curb + GAP), yaw)
        if scene.free(lo, hi, margin=0.2):
            scene.add(scene.name("StreetLight"), "street_light", parts, (lx, y, curb + GAP), yaw)
            th = np.radians(yaw)
            head = (lx + 1.1 * np.cos(th), y + 1.1 * np.sin(th), curb + GAP + lamp_h)
            if k % 2 == 0:  # alternate point lamps and downward spots
                b.sphere_light(f"Lamp_{k:02d}", head, 0.12, float(rng.uniform(150, 400)))
            else:
                b.spot_light(f"Lamp_{k:02d}", head, (head[0], head[1], 0.0), 0.1, float(rng.uniform(300, 700)),
                             float(rng.uniform(35, 60)))
        lx += float(rng.uniform(10, 16))
        k += 1

    # People on the pavements, trees on the verges in front of the buildings.
    for _ in range(int(rng.integers(3, 7))):
        parts = scene.draw("person", kit.person)
        s = 1 if rng.random() < 0.5 else -1
        y0, y1 = sorted((s * (road_w + 0.6), s * (road_w + walk_w - 0.2)))
        pose = scene.place(parts, ((-L / 2 + 2, y0), (L / 2 - 2, y1)), curb + GAP, margin=0.3)
        if pose:
            scene.add(scene.name("Person"), "person", parts, pose[0], pose[1])
    for _ in range(int(rng.integers(2, 6))):
        parts = scene.draw("tree", kit.tree)
        s = 1 if rng.random() < 0.5 else -1
        y0, y1 = sorted((s * (road_w + walk_w + 0.2), s * (road_w + walk_w + verge - 0.5)))
        pose = scene.place(parts, ((-L / 2 + 2, y0), (L / 2 - 2, y1)), GAP, margin=0.3)
        if pose:
            scene.add(scene.name("Tree"), "tree", parts, pose[0], pose[1])

    scene.lighting = b.lighting(rng, ("sun", "sun", "overcast", "night"))
    # Street furniture on the verge's edge behind the pavement: benches facing the road, bins, railings.
    for kind, count in (("bench", (1, 4)), ("litter_bin", (1, 4)), ("railing", (1, 3))):
        for _ in range(int(rng.integers(*count))):
            s = 1 if rng.random() < 0.5 else -1
            if kind == "railing":
                parts, yaw, depth = kit.railing(float(rng.uniform(4.0, 9.0))), 0.0, 0.2
            else:
                parts, yaw, depth = scene.draw(kind.split("_")[-1], getattr(kit, kind)), (270.0 if s > 0 else 90.0), 1.2
            y0, y1 = sorted((s * (road_w + walk_w + 0.1), s * (road_w + walk_w + 0.1 + depth)))
            pose = scene.place(parts, ((-L / 2 + 2, y0), (L / 2 - 2, y1)), GAP, yaw_choices=[yaw], margin=0.3)
            if pose:
                scene.add(scene.name(kind.split("_")[-1].capitalize()), kind.split("_")[-1], parts, pose[0], pose[1])

    def rig_position(r):
        return (r.uniform(-L / 2 + 8, L / 2 - 8), r.uniform(-road_w + 0.8, road_w - 0.8), r.uniform(1.5, 3.0))

    def look_at(r):
        return (r.uniform(-10, 10), r.uniform(-road_w - walk_w, road_w + walk_w), r.uniform(0.8, 2.0))

    return StreetSite(rig_position, look_at, road_w, walk_w, curb)


@street.dynamic
def _animate(ctx, site: StreetSite) -> StreetSite:
    from .dynamic import PERSON_RADIUS, prop_near, traffic

    road_w, walk_w, curb = site.road_w, site.walk_w, site.curb
    rng = ctx.rng
    traffic(ctx, -road_w / 2, 1, -L / 2, L / 2, int(rng.integers(2, 4)))
    if rng.random() < 0.7:
        traffic(ctx, road_w / 2, -1, -L / 2, L / 2, int(rng.integers(1, 4)))

    def spot(r):  # a loop along the middle of a pavement, clear of the kerb and the verge, beside a prop if any
        s = 1 if r.random() < 0.5 else -1
        width = float(min(0.7, walk_w - 2.0))
        length = float(r.uniform(1.2, 2.0))
        x = float(r.uniform(-L / 2 + 6, L / 2 - 6))
        y = road_w + walk_w / 2
        # beside a tree, street light, bench or bin: a rig can stand just behind the prop, a near foreground
        # that the performer passes behind. Verge props stand clear of the loop; a lamp post on the pavement
        # has the loop's sweep end 0.05-0.3 m clear of it along the pavement.
        band = sorted((s * (road_w - 1.5), s * (road_w + walk_w + 4)))  # a street light's box reaches over the road
        region = ((-L / 2 + 6, band[0]), (L / 2 - 6, band[1]))
        # half the time a street light: a rig behind its post looks along the pavement at the performer walking
        # towards it and away (near, so a large share of the view), the post in front
        near = prop_near(ctx, r, ("street_light",), region) if r.random() < 0.5 else None
        near = near or prop_near(ctx, r, ("tree", "street_light", "bench", "bin"), region)
        if near is not None:
            lo, hi, label = near
            cx, side = (lo[0] + hi[0]) / 2, 1 if r.random() < 0.5 else -1
            if label == "street_light":  # a short loop: the performer stays near a rig behind the post
                length = float(r.uniform(0.8, 1.2))
                shift = (hi[0] - lo[0]) / 2 + length / 2 + PERSON_RADIUS + float(r.uniform(0.05, 0.3))
            else:  # and the loop near the verge's edge of the pavement, the prop (behind that edge) 0.05-0.4 m beyond its sweep
                shift = float(r.uniform(0.0, 0.6))
                y = max(y, road_w + walk_w - width / 2 - PERSON_RADIUS - float(r.uniform(0.05, 0.4)))
            side = side if abs(cx + side * shift) < L / 2 - 6 else -side  # the side that stays on the street
            if abs(cx + side * shift) < L / 2 - 6:
                return ((float(cx + side * shift), s * y), curb + GAP, 0.0, length, width)
        if r.random() < 0.8:
            return None  # performer() asks again: a spot by a prop is worth several tries
        return ((x, s * y), curb + GAP, 0.0, length, width)

    ctx.spot = spot
    return site
