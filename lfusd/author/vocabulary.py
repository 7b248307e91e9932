"""lfusd's vocabulary: the semantic class names it knows and every ``lfusd:*`` name it writes
into or reads from a stage. Everything else imports these; nothing spells them out again.

Class groups (the UsdSemantics ``class`` labels lfusd gives a meaning):

- ``GROUND``: surfaces one stands, drives or builds on (the rulebook's default support of a
  person, the surfaces people are placed on);
- ``WATER``: water surfaces (boats float on them, people never stand on them);
- ``SURFACES``: both together: the scenery rather than objects (no ``any`` interpenetration
  rule, the stage's extent when it has no ``lfusd:bounds``, no occupancy in generated scenes);
- ``OBJECTS``: the object classes the scene library authors and has rules for.

Property names. Style for new names: ``lfusd:<namespace>:<name>`` with a snake_case ``<name>``
that is the same word as in Python, rules files and the command line (as the rig fields and
rule kinds already are). Two older names keep their camelCase because files already carry
them: the attribute ``lfusd:wheelRadius`` and the clip metadata key ``lfusd:cycleFrames``.
"""

from __future__ import annotations

# -- semantic classes ----------------------------------------------------------------------------
GROUND = ("road", "pavement", "sidewalk", "ground", "grass", "floor", "bridge", "stairs", "terrain", "dirt")
WATER = ("water", "river", "lake", "sea")
SURFACES = frozenset(GROUND + WATER)
OBJECTS = ("person", "boat", "car", "building", "tree", "street_light", "bench", "table", "chair", "cabinet",
           "lamp", "bowl", "wall", "bin", "railing", "shelf", "shape")
ANY = "any"  # in rules: every labelled object that is not a surface
# (least, most) metres of a catalogue asset's longest side per class a template draws: an asset
# outside is flagged when added (a car in centimetres read as metres is a 467 m car)
PLAUSIBLE_SIZE = {"person": (0.5, 2.6), "car": (2.0, 12.0), "tree": (0.5, 60.0), "bench": (0.5, 6.0), "bin": (0.2, 2.0),
                  "chair": (0.3, 1.8), "table": (0.3, 6.0), "shelf": (0.3, 6.0)}
CLASSES = frozenset(GROUND + WATER + OBJECTS)

# -- attributes and relationships ------------------------------------------------------------
RIG = "lfusd:rig:"  # + a RigSpec field (rows, focal_length_mm, look_at, ...) on a rig prim
RIG_VIEW = RIG + "view"  # int2 (row, col) on each camera of a rig
RULE = "lfusd:rule:"  # lfusd:rule:<class>:<kind>, class rules on the default prim
CONSTRAINT = "lfusd:constraint:"  # lfusd:constraint:<kind>, the rules of one object prim
BOUNDS = "lfusd:bounds"  # double3[2] (min, max corner) on the default prim
WHEEL_RADIUS = "lfusd:wheelRadius"  # double on a car's wheel* mesh
# string on an object prim placed from an asset catalogue (lfusd.author.catalogue): the asset's
# content hash. Everything drawn below it (instances, point instances) is that one object.
ASSET = "lfusd:asset"
LICENCE = "lfusd:licence"  # an asset's licence in its layer's customLayerData (read beside "license", "licence", ...)
# token on a DomeLight: "physical" asks the renderer for Blender's physical sky (lit by the stage's
# DistantLight) in place of the dome's flat colour, which stays for renderers that do not know it
SKY = "lfusd:sky"
PHYSICAL_SKY = "physical"

# -- customData of the default prim of a generated stage -------------------------------------
TEMPLATE = "lfusd:template"
SEED = "lfusd:seed"
DYNAMIC = "lfusd:dynamic"
LIGHTING = "lfusd:lighting"  # dictionary: the drawn lighting setup ("setup": sun|overcast|night|indoor, and its parameters)
DISPARITY = "lfusd:disparity"  # dictionary: the disparity design of a training stage (things: shift_px, range_px, ...)

# -- customLayerData of a gait clip (animations/*.usda) ----------------------------------------
GAIT = "lfusd:gait"
SPEED = "lfusd:speed"
CYCLE_FRAMES = "lfusd:cycleFrames"
STRIDE = "lfusd:stride"


def rig_attr(field: str) -> str:
    """``lfusd:rig:<field>``."""
    return RIG + field


def rule_attr(cls: str, kind: str) -> str:
    """``lfusd:rule:<cls>:<kind>``."""
    return f"{RULE}{cls}:{kind}"


def constraint_attr(kind: str) -> str:
    """``lfusd:constraint:<kind>``."""
    return CONSTRAINT + kind
