"""Object kits for the templates: lists of (part name, mesh, texture) in the object's local frame.

Every kit has its lowest point at local z = 0 and faces +x, so a template places it by the
support height alone.
"""

from __future__ import annotations

import numpy as np

from .build import MeshData, bowl, box, cylinder, moved, prism

PAINTS = ("paint_red", "paint_blue", "paint_white", "paint_yellow", "paint_dark")

Parts = list[tuple[str, MeshData, str]]


def car(rng: np.random.Generator) -> Parts:
    length, width = rng.uniform(3.8, 4.6), rng.uniform(1.7, 1.9)
    paint = PAINTS[int(rng.integers(len(PAINTS)))]
    r, w = 0.32, 0.22
    body = box((length, width, 0.6), (0.0, 0.0, 0.25 + 0.3), tile=2.0)
    cabin = box((length * 0.5, width * 0.9, 0.5), (-0.1 * length, 0.0, 0.85 + 0.25), tile=2.0)
    wheels = [moved(cylinder(r, -w / 2, w / 2, 12, axis="y"), (sx * length * 0.32, sy * (width / 2 - w / 2), r))
              for sx in (-1, 1) for sy in (-1, 1)]
    return [("body", body, paint), ("cabin", cabin, "paint_dark"), ("wheels", _merge(wheels), "paint_dark")]


def person(rng: np.random.Generator) -> Parts:
    h = rng.uniform(1.6, 1.9)
    shirt = ("fabric", "paint_blue", "paint_red", "paint_white")[int(rng.integers(4))]
    leg = h * 0.47
    legs = _merge([box((0.14, 0.13, leg), (0.0, s * 0.1, leg / 2), tile=0.5) for s in (-1, 1)])
    torso = box((0.24, 0.44, h * 0.33), (0.0, 0.0, leg + h * 0.165), tile=0.5)
    arms = _merge([box((0.1, 0.09, h * 0.32), (0.0, s * 0.275, leg + h * 0.16), tile=0.5) for s in (-1, 1)])
    head = cylinder(0.1, leg + h * 0.34, h, 12, tile=0.3)
    return [("legs", legs, "paint_dark"), ("torso", torso, shirt), ("arms", arms, shirt), ("head", head, "plaster")]


def tree(rng: np.random.Generator) -> Parts:
    h = rng.uniform(3.5, 6.0)
    trunk = cylinder(0.15, 0.0, h * 0.5, 10, radius_top=0.1, tile=1.0)
    crown = cylinder(rng.uniform(1.0, 1.6), h * 0.35, h, 12, radius_top=0.15, tile=1.0)
    return [("trunk", trunk, "bark"), ("crown", crown, "leaves")]


def street_light(rng: np.random.Generator) -> tuple[Parts, float]:
    """A pole with an arm towards +x; returns (parts, lamp height) — the light sits under the head."""
    h = rng.uniform(4.5, 6.0)
    pole = cylinder(0.08, 0.0, h, 10, radius_top=0.06, tile=1.0)
    arm = box((1.2, 0.1, 0.1), (0.6, 0.0, h - 0.05), tile=1.0)
    head = box((0.5, 0.3, 0.12), (1.1, 0.0, h - 0.16), tile=1.0)
    return [("pole", pole, "concrete"), ("arm", _merge([arm, head]), "paint_dark")], h - 0.22


def bench(rng: np.random.Generator) -> Parts:
    length = rng.uniform(1.5, 2.0)
    seat = box((0.45, length, 0.06), (0.0, 0.0, 0.45), tile=0.5)
    back = box((0.06, length, 0.45), (-0.2, 0.0, 0.75), tile=0.5)
    legs = _merge([box((0.4, 0.06, 0.42), (0.0, s * (length / 2 - 0.1), 0.21), tile=0.5) for s in (-1, 1)])
    return [("seat", _merge([seat, back]), "wood"), ("legs", legs, "paint_dark")]


def building(rng: np.random.Generator, width: float, depth: float) -> tuple[Parts, float]:
    floors = int(rng.integers(2, 6))
    h = floors * 3.0
    walls = box((width, depth, h), (0.0, 0.0, h / 2), tile=3.0)
    roof = box((width + 0.3, depth + 0.3, 0.3), (0.0, 0.0, h + 0.15), tile=2.0)
    return [("walls", walls, "bricks"), ("roof", roof, "concrete")], h


def boat(rng: np.random.Generator) -> tuple[Parts, float]:
    """A hull (pointed bow towards +x) and a cabin; returns (parts, draft)."""
    length, width = rng.uniform(4.0, 6.5), rng.uniform(1.6, 2.2)
    depth = 0.9
    outline = [(-length / 2, -width / 2), (length * 0.25, -width / 2), (length / 2, 0.0),
               (length * 0.25, width / 2), (-length / 2, width / 2)]
    hull = prism(outline, 0.0, depth, tile=1.0)
    cabin = box((length * 0.3, width * 0.6, 0.8), (-length * 0.15, 0.0, depth + 0.4), tile=1.0)
    paint = PAINTS[int(rng.integers(len(PAINTS)))]
    return [("hull", hull, paint), ("cabin", cabin, "wood")], float(rng.uniform(0.25, 0.45))


def table(rng: np.random.Generator) -> tuple[Parts, float, tuple[float, float]]:
    """Returns (parts, top height, top size)."""
    lx, ly, h = rng.uniform(1.2, 1.8), rng.uniform(0.8, 1.0), 0.75
    top = box((lx, ly, 0.04), (0.0, 0.0, h - 0.02), tile=1.0)
    legs = _merge([box((0.06, 0.06, h - 0.04), (sx * (lx / 2 - 0.06), sy * (ly / 2 - 0.06), (h - 0.04) / 2))
                   for sx in (-1, 1) for sy in (-1, 1)])
    return [("top", top, "wood"), ("legs", legs, "wood")], h, (lx, ly)


def chair(rng: np.random.Generator) -> Parts:
    """A chair whose back is at -x: it faces +x."""
    s = 0.45
    seat = box((s, s, 0.04), (0.0, 0.0, 0.45), tile=0.5)
    back = box((0.04, s, 0.5), (-s / 2 + 0.02, 0.0, 0.72), tile=0.5)
    legs = _merge([box((0.04, 0.04, 0.43), (sx * (s / 2 - 0.03), sy * (s / 2 - 0.03), 0.215)) for sx in (-1, 1) for sy in (-1, 1)])
    fabric = ("fabric", "paint_red", "paint_blue")[int(rng.integers(3))]
    return [("seat", _merge([seat, back]), fabric), ("legs", legs, "wood")]


def bowl_kit(rng: np.random.Generator) -> Parts:
    return [("bowl", bowl(rng.uniform(0.08, 0.14), rng.uniform(0.06, 0.1)), "ceramic")]


def floor_lamp(rng: np.random.Generator) -> tuple[Parts, float]:
    """Returns (parts, light height) — the light hangs inside the open-bottomed shade."""
    h = rng.uniform(1.5, 1.8)
    base = cylinder(0.18, 0.0, 0.04, 12)
    pole = cylinder(0.02, 0.04, h - 0.25, 8)
    shade = cylinder(0.22, h - 0.25, h, 12, radius_top=0.14)
    return [("stand", _merge([base, pole]), "paint_dark"), ("shade", shade, "fabric")], h - 0.4


def cabinet(rng: np.random.Generator) -> Parts:
    w, d, h = rng.uniform(0.8, 1.4), 0.45, rng.uniform(0.8, 1.9)
    return [("carcass", box((d, w, h), (0.0, 0.0, h / 2), tile=1.0), "wood")]


def _merge(parts):
    from .build import merge

    return merge(*parts)


def moving_car(rng: np.random.Generator) -> tuple[Parts, list[tuple[str, tuple[float, float, float], MeshData]], float]:
    """A car whose wheels are separate parts: (body parts, [(wheel name, hub in car frame, wheel mesh
    centred on its hub with the axle along Y)], wheel radius). Lowest point at z = 0, facing +x."""
    length, width = rng.uniform(3.8, 4.6), rng.uniform(1.7, 1.9)
    paint = PAINTS[int(rng.integers(len(PAINTS)))]
    r, w = 0.32, 0.22
    body = box((length, width, 0.6), (0.0, 0.0, 0.25 + 0.3), tile=2.0)
    cabin = box((length * 0.5, width * 0.9, 0.5), (-0.1 * length, 0.0, 0.85 + 0.25), tile=2.0)
    tyre = cylinder(r, -w / 2, w / 2, 12, axis="y")
    # The tyres stand 2 cm proud of the body's sides: a tyre cap coplanar with the body would be
    # a surface that spins and one that does not in one plane (ambiguous hits, wrong flow).
    wheels = [(f"wheel_{'F' if sx > 0 else 'R'}{'L' if sy > 0 else 'R'}", (sx * length * 0.32, sy * (width / 2 - w / 2 + 0.02), r), tyre)
              for sx in (-1, 1) for sy in (-1, 1)]
    return [("body", body, paint), ("cabin", cabin, "paint_dark")], wheels, r


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
