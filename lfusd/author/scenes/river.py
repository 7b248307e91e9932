"""River: water between grass banks (vertical bank walls, a dirt riverbed), a bridge with
railings, floating boats, trees, benches and people on the banks and the bridge; sun and sky,
with a disk light (a spot on the bridge)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import GAP, Scene, Site, template
from . import objects as kit
from .build import box, merge, moved

L = 60.0


@dataclass(frozen=True)
class RiverSite(Site):
    half: float  # river half width (y)
    level: float  # water surface height
    bank: float  # bank width
    bx: float  # bridge centre (x)
    bw: float  # bridge width
    span: float  # half length of the bridge deck (y)
    deck_z: float  # height of the deck's walking surface


@template("river", seed_key=1, labels={"water", "grass", "bridge", "boat", "person", "tree"}, movers={"person", "boat"})
def river(scene: Scene) -> RiverSite:
    rng, b = scene.rng, scene.builder
    half = float(rng.uniform(4.5, 7.0))  # river half width (y)
    level = -float(rng.uniform(0.4, 0.8))  # water surface height
    bed = -2.5
    bank = 20.0
    scene.bounds = ((-L / 2, -(half + bank)), (L / 2, half + bank))

    scene.add("/World/River", "water", [("surface", box((L, 2 * half, level - bed), (0, 0, (level + bed) / 2), tile=4.0), "water")], track=False)
    scene.add("/World/Riverbed", "ground", [("surface", box((L, 2 * half, 0.5), (0, 0, bed - 0.25), tile=3.0), "dirt")], track=False)
    for side, s in (("N", 1), ("S", -1)):
        scene.add(f"/World/Bank_{side}", "grass", [("surface", box((L, bank, 3.0), (0, s * (half + bank / 2), -1.5), tile=3.0), "grass")], track=False)

    # Bridge across the river: deck on two abutments resting on the banks, railings on the deck.
    bx = float(rng.uniform(-10, 10))
    bw = float(rng.uniform(2.5, 4.0))
    span = half + 3.0
    deck_z = 0.6
    deck = box((bw, 2 * span, 0.3), (0, 0, deck_z - 0.15), tile=2.0)
    abutments = merge(*[box((bw, 2.5, deck_z - 0.3), (0, s * (span - 1.25), (deck_z - 0.3) / 2), tile=2.0) for s in (1, -1)])
    rails = merge(*[moved(d, (s * (bw / 2 - 0.04), 0.0, deck_z + GAP)) for s in (1, -1)
                    for _, d, _ in kit.railing(2 * span - 0.1, 1.0, 1.5, along="y")])
    scene.add("/World/Bridge", "bridge", [("deck", deck, "concrete"), ("abutments", abutments, "concrete"),
                                          ("railings", rails, "metal")], (bx, 0.0, GAP))
    bridge_box = scene.placed[-1]

    # Boats float with their draft below the water level; keep them clear of the bridge.
    for _ in range(int(rng.integers(2, 5))):
        parts, draft = kit.boat(rng)
        pose = scene.place(parts, ((-L / 2 + 3, -half + 0.5), (L / 2 - 3, half - 0.5)), level - draft,
                           yaw_choices=[0.0, 180.0, 10.0, 190.0, -10.0, 170.0], margin=0.8)
        if pose:
            scene.add(scene.name("Boat"), "boat", parts, pose[0], pose[1])

    # People: on the banks and on the bridge deck.
    for _ in range(int(rng.integers(3, 7))):
        parts = scene.draw("person", kit.person)
        if rng.random() < 0.3:
            region = ((bx - bw / 2 + 0.4, -span + 2.6), (bx + bw / 2 - 0.4, span - 2.6))
            z = deck_z + 2 * GAP
            pose = scene.place(parts, region, z, margin=0.2, ignore=(bridge_box.path,))
        else:
            s = 1 if rng.random() < 0.5 else -1
            y0, y1 = sorted((s * (half + 0.5), s * (half + 8.0)))
            pose = scene.place(parts, ((-L / 2 + 2, y0), (L / 2 - 2, y1)), GAP, margin=0.3)
        if pose:
            scene.add(scene.name("Person"), "person", parts, pose[0], pose[1])
    for _ in range(int(rng.integers(3, 8))):
        parts = scene.draw("tree", kit.tree)
        s = 1 if rng.random() < 0.5 else -1
        y0, y1 = sorted((s * (half + 2.0), s * (half + bank - 1.0)))
        pose = scene.place(parts, ((-L / 2 + 2, y0), (L / 2 - 2, y1)), GAP, margin=0.3)
        if pose:
            scene.add(scene.name("Tree"), "tree", parts, pose[0], pose[1])
    for _ in range(int(rng.integers(1, 4))):
        parts = scene.draw("bench", kit.bench)
        s = 1 if rng.random() < 0.5 else -1
        y0, y1 = sorted((s * (half + 1.0), s * (half + 6.0)))
        pose = scene.place(parts, ((-L / 2 + 2, y0), (L / 2 - 2, y1)), GAP, yaw_choices=[90.0 if s < 0 else 270.0], margin=0.3)
        if pose:
            scene.add(scene.name("Bench"), "bench", parts, pose[0], pose[1])

    # Railings along the water's edge and bins on the banks.
    for _ in range(int(rng.integers(1, 4))):
        s = 1 if rng.random() < 0.5 else -1
        parts = kit.railing(float(rng.uniform(5.0, 12.0)))
        y0, y1 = sorted((s * (half + 0.15), s * (half + 0.45)))
        pose = scene.place(parts, ((-L / 2 + 2, y0), (L / 2 - 2, y1)), GAP, yaw_choices=[0.0], margin=0.3)
        if pose:
            scene.add(scene.name("Railing"), "railing", parts, pose[0], pose[1])
    for _ in range(int(rng.integers(1, 3))):
        parts = scene.draw("bin", kit.litter_bin)
        s = 1 if rng.random() < 0.5 else -1
        y0, y1 = sorted((s * (half + 1.0), s * (half + 6.0)))
        pose = scene.place(parts, ((-L / 2 + 2, y0), (L / 2 - 2, y1)), GAP, margin=0.3)
        if pose:
            scene.add(scene.name("Bin"), "bin", parts, pose[0], pose[1])
    b.disk_light("BridgeSpot", (bx, 0.0, deck_z + 5.0), (bx, 0.0, deck_z), 0.3, float(rng.uniform(100, 300)))
    scene.lighting = b.lighting(rng, ("sun", "sun", "overcast", "night"))

    def rig_position(r):
        s = 1 if r.random() < 0.5 else -1
        return (r.uniform(-L / 2 + 8, L / 2 - 8), s * r.uniform(half + 0.5, half + 4.0), r.uniform(1.6, 3.5))

    def look_at(r):
        return (bx + r.uniform(-12, 12), r.uniform(-half, half), r.uniform(level, 1.5))

    return RiverSite(rig_position, look_at, half, level, bank, bx, bw, span, deck_z + GAP)


@river.dynamic
def _animate(ctx, site: RiverSite) -> None:
    from .dynamic import boats, loop_beside, walker

    half, level = site.half, site.level
    bx, bw, span, deck = site.bx, site.bw, site.span, site.deck_z
    rng = ctx.rng
    boats(ctx, level, -L / 2 + 0.5, L / 2 - 0.5, -half + 0.1, half - 0.1)
    if rng.random() < 0.7:  # someone crossing the bridge
        for _ in range(20):
            s = 1 if rng.random() < 0.5 else -1
            x = bx + float(rng.uniform(-(bw / 2 - 0.7), bw / 2 - 0.7))
            if walker(ctx, (x, -s * (span - 0.6)), (0.0, s), deck, "walk", float(rng.uniform(1.0, 1.5)), 2 * span - 1.2):
                break
    # the bridge (a surface, so not in the occupancy) is no place for bank walkers to pass under or climb
    ctx.occ.boxes.append(("bridge", np.array([bx - bw / 2 - 0.4, -span - 0.6, -5.0]), np.array([bx + bw / 2 + 0.4, span + 0.6, 5.0])))

    def spot(r):  # a loop along a bank, between the water's edge and the trees, beside a bench, bin or tree if any
        s = 1 if r.random() < 0.5 else -1
        centre = (float(r.uniform(-L / 2 + 6, L / 2 - 6)), s * float(r.uniform(half + 1.8, half + 5.0)))
        heading, length, width = float(r.choice([0.0, 90.0])), float(r.uniform(1.2, 2.0)), float(r.uniform(0.4, 0.7))
        # just clear of a prop (a rig behind it has a near foreground the performer passes behind): a bench or
        # bin (small enough for a rig near the loop to look past), else a tree
        region = ((-L / 2 + 6, -half - 8.0), (L / 2 - 6, half + 8.0))
        near = loop_beside(ctx, r, ("bench", "bin"), region, length, width)
        if near is None:
            near = loop_beside(ctx, r, ("tree",), region, length, width, gap=(0.9, 1.6))
        if near is not None and half + 1.8 <= abs(near[0][1]) <= half + 6.0:
            centre, heading = (float(near[0][0]), float(near[0][1])), near[1]
        elif r.random() < 0.8:
            return None  # performer() asks again: a spot by a prop is worth several tries
        return (centre, GAP, heading, length, width)

    ctx.spot = spot
