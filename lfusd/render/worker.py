"""Blender worker process: imports a USD stage once and renders many frames of a rig's views.

Run as ``python -m lfusd.render.worker`` with a JSON job on stdin (see ``lfusd.render.job``).
This is the only module that imports ``bpy``; it must not import usd-core's ``pxr`` (Blender
carries its own USD, see docs/blender-facts.md). It talks back through stdout lines
starting with ``LFUSD `` followed by JSON; everything else on stdout is Blender's chatter.

Per frame it renders twice, into a scratch folder the parent owns:
- beauty: the user's samples and Blender's default pixel filter, linear RGB EXR per view;
- data: 1 sample with a box filter of tiny width, so every ground-truth pass (depth, normal,
  position, object index, vector) is the exact value at the pixel centre. No pass of it depends on
  light or shading, so it renders with the lights hidden, no world and one opaque material in
  place of the scene's (data_material).
The views go through these two renders in chunks of at most ``WorkUnit.render_pixels`` pixels
(lfusd.render.plan.view_chunks): a multiview render result holds every enabled view's passes at
once, so memory stays bounded whatever the grid. After each chunk the worker hands its files to the
parent (a ``frame`` event) and goes on rendering while the parent checks, moves and derives them.
"""

from __future__ import annotations

import json
import os
import re
import sys
import tempfile
import time
import traceback

import bpy
import numpy as np

from lfusd import cpu_account
from lfusd.data.folder import atomic_write
from lfusd.data.formats import link_or_copy
from lfusd.keys import EMISSIVE, MATERIAL_AOV, MIRROR, MOTION_AOVS, PASS_SWITCHES, TRANSMISSIVE
from lfusd.processes import PARENT_PID_ENV, die_with_parent
from lfusd.render.plan import WorkUnit, view_chunks

bpy.utils.expose_bundled_modules()  # Blender's USD hooks hand out objects of its bundled pxr

PRIM_MAP: dict[str, list] = {}
# Where Cycles puts its single sample inside a pixel with a 0.01-wide box filter, measured with
# bpy 5.0.1 (the same for every seed): (+0.000486, +0.000474) px in raster axes (x right, y up).
# The data render shifts the lens by the opposite so the sample lands on the pixel centre; the
# test suite measures the residual from the position pass.
SAMPLE_OFFSET_PX = (0.000486, 0.000474)
# Where the data render's one sample lands through the OSL lens camera (lfusd.render.lens), from the
# pixel centre in pixel axes (u right, v down), measured with bpy 5.0 from the position pass against
# cv2.projectPoints (tests/render/test_lens_render.py): the shader takes it off every sample. The OSL
# camera ignores the lens shift that puts SAMPLE_OFFSET_PX right.
LENS_SAMPLE_OFFSET_PX = (0.0000024, -0.000128)
VIEW_PREFIX = "lfusd_view"
NON_GEOMETRY = ("EMPTY", "CAMERA", "LIGHT", "ARMATURE")


def emit(kind: str, **data) -> None:
    sys.stdout.write("LFUSD " + json.dumps({"event": kind, **data}) + "\n")
    sys.stdout.flush()


def warn(message: str) -> None:
    """A warning for the user: into this worker's log, and to the parent, which shows it."""
    print(f"lfusd: warning: {message}", file=sys.stderr)
    emit("warning", message=message)


class _PrimMapHook(bpy.types.USDHook):
    bl_idname = "lfusd_prim_map"
    bl_label = "lfusd prim map"

    @staticmethod
    def on_import(context):
        for path, ids in context.get_prim_map().items():
            PRIM_MAP[str(path)] = list(ids)


def _objects_of(prim_path: str) -> list:
    return [i for i in PRIM_MAP.get(prim_path, []) if isinstance(i, bpy.types.Object)]


# Options that put Blender's import in lfusd's world (Z-up, metres; measured with bpy 5.0.1):
# the importer rotates a Y-up stage +90 degrees about X and scales by metersPerUnit, on the
# matrices of root objects, so every object's matrix_world, evaluated vertex and world-space
# pass (position, normal) is in lfusd's world, as are cameras (their lens follows the same units).
WORLD_IMPORT_OPTIONS = {"scale": 1.0, "apply_unit_conversion_scale": True}
# A root Xform translated by (1, 2, 3) scene units, on a stage with the job's axes and units.
_PROBE = """#usda 1.0
(
    upAxis = "{up}"
    metersPerUnit = {mpu!r}
)
def Xform "lfusd_world_probe"
{{
    double3 xformOp:translate = (1, 2, 3)
    uniform token[] xformOpOrder = ["xformOp:translate"]
}}
"""


def check_world_import(world: dict) -> None:
    """Import a probe stage with the stage's up axis and metersPerUnit, and raise unless
    Blender puts it where lfusd's map of the stage into its world (``world["stage_to_world"]``)
    does: then Blender's world is lfusd's world, and every pass and pose agrees with pxr's."""
    expected = np.array(world["stage_to_world"], np.float64) @ np.array([[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]], np.float64)
    with tempfile.TemporaryDirectory(prefix="lfusd_probe") as tmp:
        path = os.path.join(tmp, "probe.usda")
        with open(path, "w") as f:
            f.write(_PROBE.format(up=world["up_axis"], mpu=float(world["meters_per_unit"])))
        before = set(bpy.data.objects)
        bpy.ops.wm.usd_import(filepath=path, set_frame_range=False, **WORLD_IMPORT_OPTIONS)
        probes = [o for o in bpy.data.objects if o not in before]
        got = np.array(probes[0].matrix_world, np.float64) if len(probes) == 1 else None
        for o in probes:
            bpy.data.objects.remove(o, do_unlink=True)
    PRIM_MAP.clear()
    scale = float(world["meters_per_unit"])
    if got is None or not np.allclose(got, expected, rtol=1e-5, atol=1e-6 * scale):
        landed = "nowhere" if got is None else f"at {np.round(got[:3, 3], 6).tolist()}"
        raise RuntimeError(
            f"Blender's USD import does not map upAxis {world['up_axis']}, metersPerUnit {scale:g} into lfusd's Z-up metre world "
            f"(stage point (1, 2, 3) landed {landed}, not at {np.round(expected[:3, 3], 6).tolist()}); use bpy 5.0.x"
        )


def import_stage(path: str, has_dome: bool = False, world: dict | None = None) -> None:
    """Import the stage into an empty scene, in lfusd's world (checked against ``world``, the
    stage's WorldFrame.to_dict(), when given)."""
    bpy.utils.register_class(_PrimMapHook)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    if world:
        check_world_import(world)
    if has_dome:  # the importer turns a DomeLight into the world only if a world already exists
        bpy.context.scene.world = bpy.data.worlds.new("World")
    result = bpy.ops.wm.usd_import(
        filepath=path,
        import_skeletons=True,
        import_blendshapes=True,
        import_lights=True,
        import_cameras=True,
        set_frame_range=False,
        read_mesh_attributes=True,
        **WORLD_IMPORT_OPTIONS,
    )
    if "FINISHED" not in result:
        raise RuntimeError(f"Blender could not import stage {path}")


# --- What the import leaves unrenderable: importer messages, untranslated prims, materials, textures.

# Gprim types Blender 5.0's USD importer turns into geometry (generous: a false warning is worse
# than a missed one); other gprims do not render (measured: NurbsPatch and TetMesh become empties).
IMPORTED_GPRIMS = {"Mesh", "Cube", "Sphere", "Cylinder", "Cylinder_1", "Cone", "Capsule", "Capsule_1", "Plane",
                   "BasisCurves", "NurbsCurves", "Points", "Volume"}
SKIPPED_PRIMS: dict[str, list[str]] = {}  # type name -> prim paths the importer does not render
# Lines Blender prints while importing (stdout and stderr, measured with bpy 5.0.1):
# its own log ("00:00.493  io.usd  | WARNING Couldn't open image file ..."), USD's diagnostics
# ("Warning: in _ReportErrors at line 3253 of .../stage.cpp -- In </A>: Could not open asset ...")
# and the operator's reports ("Warning: ...", "Error: ...").
IMPORT_MESSAGE = re.compile(
    r"^\d+:\d+\.\d+\s+\S+\s+\|\s+(?:WARNING|ERROR)\s+(?P<clog>.+)$"
    r"|^(?:Warning|Error|Runtime Error|Coding Error): in \S+ at line \d+ of \S+ -- (?P<tf>.+)$"
    r"|^(?:Warning|Error): (?P<report>.+)$"
)
FALLBACK_GREY = 0.5  # linear base colour of the surface given to materials Blender cannot translate
# --light auto: world background (linear radiance) and sun strength (W/m^2); measured, a ground of
# albedo 0.8 renders about 0.74 linear and the fallback grey between 0.1 (shade) and 0.8.
SKY_GREY = 0.25
SUN_STRENGTH = 3.0
MISSING_IMAGE = re.compile(r"Couldn't open image file '(?P<file>[^']+)'")
_WARNED: set[str] = set()


def warn_once(message: str) -> None:
    if message not in _WARNED:
        _WARNED.add(message)
        warn(message)


class _ImportCheckHook(bpy.types.USDHook):
    bl_idname = "lfusd_import_check"
    bl_label = "lfusd import check"

    @staticmethod
    def on_import(context):
        from pxr import UsdGeom  # Blender's bundled pxr (exposed at the top of this module)

        for prim in context.get_stage().Traverse():
            name = str(prim.GetTypeName())
            if prim.IsA(UsdGeom.Gprim) and name not in IMPORTED_GPRIMS:
                SKIPPED_PRIMS.setdefault(name, []).append(str(prim.GetPath()))


class CapturedOutput:
    """Everything written to file descriptors 1 and 2 inside the block (Blender's C++ code prints
    there, not through Python); ``text`` holds it afterwards, and it is replayed into this
    worker's log. The parent reads no event from stdout meanwhile."""

    def __enter__(self) -> "CapturedOutput":
        sys.stdout.flush()
        sys.stderr.flush()
        self._file = tempfile.TemporaryFile()
        self._saved = os.dup(1), os.dup(2)
        os.dup2(self._file.fileno(), 1)
        os.dup2(self._file.fileno(), 2)
        return self

    def __exit__(self, *exc) -> None:
        sys.stdout.flush()
        sys.stderr.flush()
        for fd, saved in zip((1, 2), self._saved):
            os.dup2(saved, fd)
            os.close(saved)
        self._file.seek(0)
        self.text = self._file.read().decode("utf-8", "replace")
        self._file.close()
        sys.stderr.write(self.text)
        sys.stderr.flush()


def import_messages(text: str) -> list[str]:
    """The warnings and errors in Blender's import output, each once, in order."""
    found: dict[str, None] = {}
    for line in text.splitlines():
        m = IMPORT_MESSAGE.match(line.strip())
        if m:
            msg = next(g for g in m.groups() if g)
            found[re.sub(r"\s*<0x[0-9a-fA-F]+>", "", msg).strip()] = None  # object addresses differ per run
    return list(found)


def warn_import(text: str) -> None:
    """Pass what the importer reported, and the prims it skipped, to the user."""
    for msg in import_messages(text):
        missing = MISSING_IMAGE.search(msg)
        if missing:
            warn_once(f"texture {missing['file']} is missing or unreadable; surfaces using it render magenta")
        else:
            warn_once(f"Blender's USD import: {msg}")
    for name, paths in sorted(SKIPPED_PRIMS.items()):
        warn_once(f"Blender's USD importer does not render {len(paths)} {name} prim(s) (e.g. {paths[0]}); "
             "convert them to meshes to see them")


def _used_materials() -> list:
    mats = {s.material for o in bpy.data.objects if o.type not in NON_GEOMETRY for s in o.material_slots if s.material}
    return sorted(mats, key=lambda m: m.name)


def _material_output(mat):
    """The output node Cycles renders the material with, or None."""
    outs = [n for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial" and n.target in ("ALL", "CYCLES")]
    return next((n for n in outs if n.is_active_output), outs[0] if outs else None)


def has_surface(mat) -> bool:
    out = None if mat.node_tree is None else _material_output(mat)
    return out is not None and out.inputs["Surface"].is_linked


def fallback_surfaces() -> None:
    """Give every used material that has no surface a mid-grey Principled BSDF, with a warning.

    MaterialX-only materials (``outputs:mtlx:surface``) arrive with no nodes; Cycles renders
    those black in the beauty (the data render replaces every material, see data_material)."""
    paths = {i.as_pointer(): p for p, ids in PRIM_MAP.items() for i in ids if isinstance(i, bpy.types.Material)}
    for mat in _used_materials():
        if has_surface(mat):
            continue
        if mat.node_tree is None:
            mat.use_nodes = True
        nodes, links = mat.node_tree.nodes, mat.node_tree.links
        out = _material_output(mat) or nodes.new("ShaderNodeOutputMaterial")
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Base Color"].default_value = (FALLBACK_GREY, FALLBACK_GREY, FALLBACK_GREY, 1.0)
        links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
        out.is_active_output = True
        name = paths.get(mat.as_pointer(), mat.name)
        warn_once(f"material {name} has no surface Blender can translate (MaterialX only?); lfusd renders it neutral grey")


def warn_missing_images() -> None:
    """Name every image file a material needs that is missing or unreadable (Cycles renders it magenta)."""
    for image in bpy.data.images:
        if image.source != "FILE" or image.packed_file is not None:
            continue
        path = bpy.path.abspath(image.filepath_raw or image.filepath)
        if not os.path.isfile(path) or tuple(image.size) == (0, 0):  # size loads the file
            warn_once(f"texture {path} is missing or unreadable; surfaces using it render magenta")


def add_neutral_light(scene) -> None:
    """A neutral grey sky and a sun from above, for stages that carry no lights (--light auto)."""
    world = scene.world or bpy.data.worlds.new("lfusd_sky")
    scene.world = world
    if world.node_tree is None:
        world.use_nodes = True
    nodes = world.node_tree.nodes
    bg = next((n for n in nodes if n.bl_idname == "ShaderNodeBackground"), None) or nodes.new("ShaderNodeBackground")
    out = next((n for n in nodes if n.bl_idname == "ShaderNodeOutputWorld"), None) or nodes.new("ShaderNodeOutputWorld")
    bg.inputs["Color"].default_value = (SKY_GREY, SKY_GREY, SKY_GREY, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    world.node_tree.links.new(bg.outputs["Background"], out.inputs["Surface"])
    sun = bpy.data.objects.new("lfusd_sun", bpy.data.lights.new("lfusd_sun", "SUN"))
    sun.data.energy = SUN_STRENGTH
    sun.rotation_euler = (np.radians(40.0), 0.0, np.radians(30.0))  # 50 degrees above the horizon
    scene.collection.objects.link(sun)


# Blender's physical sky (bpy 5.0: sky_type MULTIPLE_SCATTERING, the successor of Nishita) at
# strength 1 with its sun disc off: mean radiance over the upper hemisphere (cosine of latitude
# weighted) 6.5 linear with the sun 45 degrees high, 4.2 at 10 degrees, 7.0 at 75 (measured, bpy
# 5.0.1). The worker divides by it, so the sky is on average as bright as the flat dome it replaces
# and, like a real one, darker when the sun is low.
PHYSICAL_SKY_MEAN = 6.5
# Below the horizon Blender's physical sky is black, which shows where a stage's ground ends. The
# worker shows there the sky just above the horizon at the same azimuth (the haze that distant
# ground fades into), darkening linearly with depression to GROUND_SHADE of it at GROUND_DIP (the
# sine of the depression angle, about 11.5 degrees) and below.
HORIZON_Z = 0.01  # sine of the elevation sampled for directions below the horizon (0.6 degrees)
GROUND_SHADE, GROUND_DIP = 0.5, 0.2


def use_physical_sky(scene) -> None:
    """Replace the flat colour of the world (the stage's DomeLight) with Blender's physical sky,
    its sun where the stage's brightest sun lamp (DistantLight) is and its disc off: the lamp
    lights the scene, the sky around it glows; below the horizon, the horizon's haze, darkening
    downwards (GROUND_SHADE). Only the beauty sees it (the data render has no world)."""
    suns = [o for o in scene.objects if o.type == "LIGHT" and o.data.type == "SUN" and not o.hide_render]
    world = scene.world
    out = None if world is None or world.node_tree is None else next(
        (n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeOutputWorld" and n.is_active_output), None)
    link = next(iter(out.inputs["Surface"].links), None) if out is not None else None
    bg = link.from_node if link is not None else None
    if not suns or bg is None or bg.bl_idname != "ShaderNodeBackground" or bg.inputs["Color"].is_linked:
        warn_once("the stage asks for a physical sky (lfusd:sky) but has no sun lamp (DistantLight) or no plain-colour "
                  "DomeLight; lfusd renders its dome as authored")
        return
    sun = max(suns, key=lambda o: o.data.energy)
    to_sun = np.array(sun.matrix_world.to_3x3().col[2], np.float64)  # a sun lamp shines along its local -Z
    to_sun /= np.linalg.norm(to_sun)
    nodes, links = world.node_tree.nodes, world.node_tree.links
    sky = nodes.new("ShaderNodeTexSky")
    sky.sky_type = "MULTIPLE_SCATTERING"
    sky.sun_disc = False
    sky.sun_elevation = float(np.arcsin(np.clip(to_sun[2], -1.0, 1.0)))
    # measured (bpy 5.0.1): sun_rotation r puts the sun at azimuth 90 degrees - r (from +x towards +y)
    sky.sun_rotation = float(np.pi / 2 - np.arctan2(to_sun[1], to_sun[0]))
    radiance = bg.inputs["Strength"].default_value * float(np.mean(bg.inputs["Color"].default_value[:3]))
    # the view direction with its height clamped at HORIZON_Z (renormalised) feeds the sky ...
    xyz = nodes.new("ShaderNodeSeparateXYZ")
    links.new(nodes.new("ShaderNodeTexCoord").outputs["Generated"], xyz.inputs[0])
    up = nodes.new("ShaderNodeMath")
    up.operation, up.inputs[1].default_value = "MAXIMUM", HORIZON_Z
    links.new(xyz.outputs["Z"], up.inputs[0])
    clamped = nodes.new("ShaderNodeCombineXYZ")
    for axis in "XY":
        links.new(xyz.outputs[axis], clamped.inputs[axis])
    links.new(up.outputs[0], clamped.inputs["Z"])
    unit = nodes.new("ShaderNodeVectorMath")
    unit.operation = "NORMALIZE"
    links.new(clamped.outputs[0], unit.inputs[0])
    links.new(unit.outputs["Vector"], sky.inputs["Vector"])
    # ... and below the horizon its colour is scaled by max(GROUND_SHADE, 1 - (1 - GROUND_SHADE) * depression / GROUND_DIP)
    fall = nodes.new("ShaderNodeMath")
    fall.operation, fall.use_clamp = "MULTIPLY_ADD", True
    fall.inputs[1].default_value, fall.inputs[2].default_value = (1.0 - GROUND_SHADE) / GROUND_DIP, 1.0
    links.new(xyz.outputs["Z"], fall.inputs[0])
    shade = nodes.new("ShaderNodeMath")
    shade.operation, shade.inputs[1].default_value = "MAXIMUM", GROUND_SHADE
    links.new(fall.outputs[0], shade.inputs[0])
    dim = nodes.new("ShaderNodeVectorMath")
    dim.operation = "SCALE"
    links.new(sky.outputs["Color"], dim.inputs[0])
    links.new(shade.outputs[0], dim.inputs["Scale"])
    links.new(dim.outputs["Vector"], bg.inputs["Color"])
    bg.inputs["Strength"].default_value = radiance / PHYSICAL_SKY_MEAN


def select_device(scene, device: str) -> str:
    """Enable the requested Cycles device; 'auto' prefers OptiX, then CUDA, then the CPU."""
    scene.cycles.device = "CPU"
    if device == "cpu":
        return "cpu"
    prefs = bpy.context.preferences.addons["cycles"].preferences
    for kind in (("OPTIX", "CUDA") if device == "auto" else (device.upper(),)):
        try:
            prefs.compute_device_type = kind
        except TypeError:
            continue
        prefs.get_devices()
        found = [d for d in prefs.devices if d.type == kind]
        if found:
            for d in prefs.devices:
                d.use = d.type == kind
            scene.cycles.device = "GPU"
            return kind.lower()
    if device != "auto":
        raise RuntimeError(f"Blender found no {device.upper()} device; use --device auto or --device cpu")
    return "cpu"


def setup_scene(job: WorkUnit) -> tuple[object, list[str]]:
    scene = bpy.context.scene
    # Identity comes from prim paths (never Blender names): object index = instance id.
    for prim_path, instance_id in job.instances.items():
        objs = [o for o in _objects_of(prim_path) if o.type not in NON_GEOMETRY]
        if not objs:
            # The importer merges an Xform with a single gprim child into one object, which
            # the prim map knows by the Xform's path only.
            objs = [o for o in _objects_of(prim_path.rsplit("/", 1)[0]) if o.type not in NON_GEOMETRY]
        if not objs:
            warn(f"{prim_path} has no Blender object; its pixels get instance 0")
        for obj in objs:
            obj.pass_index = int(instance_id)
    # Rename the rig's cameras so multiview finds each by its suffix.
    suffixes = []
    for key, prim_path in job.cameras.items():
        cams = [o for o in _objects_of(prim_path) if o.type == "CAMERA"]
        if not cams:
            raise RuntimeError(f"camera {prim_path} did not import into Blender")
        cam = cams[0]
        clash = bpy.data.objects.get(f"{VIEW_PREFIX}_{key}")
        if clash is not None and clash != cam:
            clash.name = f"{clash.name}_renamed"
        cam.name = f"{VIEW_PREFIX}_{key}"
        cam.data.sensor_fit = "HORIZONTAL"
        suffixes.append(f"_{key}")
    scene.camera = bpy.data.objects[f"{VIEW_PREFIX}{suffixes[0]}"]

    render = scene.render
    render.engine = "CYCLES"
    render.resolution_x, render.resolution_y = job.width, job.height
    render.resolution_percentage = 100
    render.pixel_aspect_x = render.pixel_aspect_y = 1.0
    render.use_motion_blur = False
    render.film_transparent = False
    # Data passes record the first surface a camera ray meets, however transparent (Blender's
    # default records the first one at least half opaque, chosen per sample): ground truth of a
    # window is the pane, as Open3D's ray casts in verify see it (CONVENTIONS).
    scene.view_layers[0].pass_alpha_threshold = 0.0
    render.use_persistent_data = False  # with passes switched between renders it crashes Cycles (docs/blender-facts.md)
    render.use_multiview = True
    render.views_format = "MULTIVIEW"
    for v in render.views:
        v.use = False
    for s in suffixes:
        view = render.views.new(s)  # files are named <filepath><view name>.exr
        view.camera_suffix = s
    if job.threads:
        render.threads_mode = "FIXED"
        render.threads = int(job.threads)
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.cycles.seed = 0
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    return scene, suffixes


def _dupli_signatures(dg, anchors: dict[str, str]) -> dict[tuple, tuple]:
    """{(anchor object, persistent id, object): (anchor prim path, vertex count, centroid in the
    anchor's space, prototype object, world matrix)} of every mesh Blender instances under an anchor."""
    out, centroids = {}, {}
    for inst in dg.object_instances:
        if not inst.is_instance or inst.object.type != "MESH" or inst.parent is None:
            continue
        anchor = anchors.get(inst.parent.name)
        if anchor is None:
            continue
        ob = inst.object
        if ob.name not in centroids:
            co = np.empty(len(ob.data.vertices) * 3, np.float64)
            ob.data.vertices.foreach_get("co", co)
            co = co.reshape(-1, 3)
            centroids[ob.name] = (len(co), co.mean(axis=0) if len(co) else np.zeros(3))
        n, c = centroids[ob.name]
        m = np.array(inst.matrix_world, np.float64)
        rel = np.linalg.inv(np.array(inst.parent.matrix_world, np.float64)) @ m
        # Dupli objects live only during the iteration: keep the original (the prototype object).
        out[(inst.parent.name, tuple(inst.persistent_id), ob.name)] = (anchor, n, rel[:3, :3] @ c + rel[:3, 3], ob.original, m)
    return out


def _match(parts: list, duplis: dict) -> dict[tuple, list]:
    """Pair each instanced part [anchor, id, n, cx, cy, cz, path] with the dupli whose centroid in the
    same anchor's space is nearest (within 1e-3 of a unit, same vertex count preferred); linear time
    through a grid of 1e-3 cells."""
    cell = 1e-3
    grid: dict[tuple, list] = {}
    for key, (anchor, n, c, _, _) in duplis.items():
        grid.setdefault((anchor, *np.floor(c / cell).astype(int)), []).append((key, n, c))
    taken, out = set(), {}
    for part in parts:
        anchor, n, c = part[0], part[2], np.asarray(part[3:6], np.float64)
        base = np.floor(c / cell).astype(int)
        best = None
        for d in np.ndindex(3, 3, 3):
            for key, m, cd in grid.get((anchor, *(base + np.array(d) - 1)), ()):
                if key in taken:
                    continue
                score = (m != n, float(np.linalg.norm(cd - c)))
                if score[1] <= cell and (best is None or score < best[0]):
                    best = (score, key)
        if best is not None:
            taken.add(best[1])
            out[best[1]] = part
    return out


def realize_instances(scene, job: WorkUnit) -> None:
    """Make every instanced gprim (scenegraph instance, point instance) a real object of its own:
    object index = its instance id, its own mesh data (for the motion AOVs) and its Blender-evaluated
    world matrix keyed at every frame the job renders or reads (t, t+/-1). Blender's instancers
    (collection-instance empties, point clouds with a Geometry Nodes instancer) stop rendering."""
    if not job.instanced:
        return
    first, last = job.stage_range
    # The prim map may name a PointInstancer by its point cloud data only: find its object through it.
    users: dict[int, list] = {}
    for o in scene.objects:
        if o.data is not None:
            users.setdefault(o.data.as_pointer(), []).append(o)
    anchors = {}
    for path in {p[0] for p in job.instanced}:
        for i in PRIM_MAP.get(path, []):
            for o in [i] if isinstance(i, bpy.types.Object) else users.get(i.as_pointer(), []):
                anchors[o.name] = path
    scene.frame_set(first)  # the parent measured the centroids at the stage's first frame
    duplis = _dupli_signatures(bpy.context.evaluated_depsgraph_get(), anchors)
    matched = _match(job.instanced, duplis)
    if len(matched) < len(job.instanced):
        done = {id(q) for q in matched.values()}
        missing = [p[6] for p in job.instanced if id(p) not in done]
        warn(f"{len(missing)} instanced gprims (e.g. {missing[0]}) have no Blender instance; their pixels get instance 0")
    coll = bpy.data.collections.new("lfusd_instances")
    scene.collection.children.link(coll)
    realized = {}
    for key, (_, _, _, ob, m) in duplis.items():
        part = matched.get(key)
        real = bpy.data.objects.new(f"lfusd_{part[1] if part else 0}_{ob.name}", ob.data.copy())
        coll.objects.link(real)
        real.pass_index = int(part[1]) if part else 0
        real.rotation_mode = "QUATERNION"
        realized[key] = (real, [])
    if len(duplis) > len(matched):
        warn(f"{len(duplis) - len(matched)} Blender instances match no instanced gprim of the stage; their pixels get instance 0")
    for name in anchors:
        bpy.data.objects[name].hide_render = True
    frames = sorted({g for f in job.frames for g in (f - 1, f, f + 1) if first <= g <= last})
    # keys interpolate linearly between frames, as USD's samples do: what --shutter's motion blur
    # sees between them (the keys themselves are exact at every frame whatever the interpolation)
    bpy.context.preferences.edit.keyframe_new_interpolation_type = "LINEAR"
    for f in frames:
        scene.frame_set(f)
        for inst in bpy.context.evaluated_depsgraph_get().object_instances:
            if inst.is_instance and inst.parent is not None:
                entry = realized.get((inst.parent.name, tuple(inst.persistent_id), inst.object.name))
                if entry is not None:
                    entry[1].append((f, inst.matrix_world.copy()))
    for real, poses in realized.values():
        if not poses:
            continue
        real.matrix_world = poses[0][1]
        if all(p == poses[0][1] for _, p in poses[1:]):
            continue  # static: no keys
        for f, p in poses:
            real.matrix_world = p
            for prop in ("location", "rotation_quaternion", "scale"):
                real.keyframe_insert(prop, frame=f)
    scene.frame_set(first)


# The t+1 / t-1 position AOVs of the raw-pass contract (lfusd.keys.RAW_PASSES): mesh attribute
# lfusd_<neighbour> -> AOV name.
NEIGHBOUR_AOVS = {p.neighbour: p.layer for p in MOTION_AOVS}


class MotionAttributes:
    """Per-vertex world positions at t+1 and t-1 on every mesh, read by AOVs of the data material.

    At one sample on the pixel centre the AOV is the barycentric blend of the hit triangle's
    vertex positions at t+/-1: the exact position then of the surface point seen at t, visible
    or not. Needs meshes whose vertex count does not change over time (rigid, skinned).
    """

    def __init__(self, scene, first: int, last: int):
        self.scene, self.first, self.last = scene, first, last
        self.meshes = [o for o in scene.objects if o.type == "MESH"]
        self.names = {o.as_pointer(): p for p, ids in PRIM_MAP.items() for o in ids if isinstance(o, bpy.types.Object)}
        self.unknown: dict[str, set[int]] = {}  # mesh name -> frames whose t+/-1 motion is unknown (topology changed)
        # World vertices by frame. Frame t needs t-1 and t+1; t-1 was frame t-2's t+1, so consecutive
        # frames evaluate the scene at one new time each (t+1), not two.
        self.cache: dict[int, dict[str, np.ndarray]] = {}
        self.evaluations = 0
        for obj in self.meshes:
            if obj.data.users > 1:  # attributes live on mesh data: give each object its own
                obj.data = obj.data.copy()
            for key in NEIGHBOUR_AOVS:
                if f"lfusd_{key}" not in obj.data.attributes:
                    obj.data.attributes.new(f"lfusd_{key}", "FLOAT_VECTOR", "POINT")
        vl = scene.view_layers[0]
        for name in NEIGHBOUR_AOVS.values():
            if name not in vl.aovs:
                aov = vl.aovs.add()
                aov.name, aov.type = name, "COLOR"

    def _world_vertices(self, frame: int) -> dict[str, np.ndarray]:
        """Every mesh's evaluated vertices at ``frame`` in lfusd's world: matrix_world already
        holds the importer's map of the stage's axes and units (checked by check_world_import)."""
        if frame not in self.cache:
            self.evaluations += 1
            self.scene.frame_set(frame)
            dg = bpy.context.evaluated_depsgraph_get()
            out = {}
            for obj in self.meshes:
                ev = obj.evaluated_get(dg)
                me = ev.to_mesh()
                co = np.empty(len(me.vertices) * 3, np.float64)
                me.vertices.foreach_get("co", co)
                m = np.array(ev.matrix_world, dtype=np.float64)
                corners = np.empty(len(me.loops), np.int32)  # face-vertex indices: the topology
                me.loops.foreach_get("vertex_index", corners)
                sizes = np.empty(len(me.polygons), np.int32)
                me.polygons.foreach_get("loop_total", sizes)
                out[obj.name] = (co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3], corners, sizes)
                ev.to_mesh_clear()
            self.cache[frame] = out
        return self.cache[frame]

    def _prim(self, obj) -> str:
        return self.names.get(obj.as_pointer(), obj.name)

    def set_frame(self, frame: int) -> None:
        """Fill the attributes for ``frame`` and go there. NaN where t+/-1 is outside the stage, and
        on a mesh whose topology (vertex count, face sizes or face-vertex indices) differs between t
        and t+/-1: vertex i at t is then not vertex i at t+/-1, so its motion is unknown (the
        derivation flags those pixels invalid; one warning names the prim)."""
        here = self._world_vertices(frame)
        for key, other in (("next", frame + 1), ("prev", frame - 1)):
            known = self.first <= other <= self.last
            verts = self._world_vertices(other) if known else None
            for obj in self.meshes:
                attr = obj.data.attributes[f"lfusd_{key}"]
                n = len(obj.data.vertices)
                v = verts[obj.name][0] if known else None
                if known and not _same_topology(here[obj.name], verts[obj.name], n):
                    v = None
                    if obj.name not in self.unknown:
                        warn(f"mesh {self._prim(obj)} changes its topology (face-vertex indices) between frames {min(frame, other)} "
                             f"and {max(frame, other)}; its motion there is unknown and its pixels are flagged invalid")
                    self.unknown.setdefault(obj.name, set()).add(frame)
                if v is None:
                    v = np.full((n, 3), np.nan)
                attr.data.foreach_set("vector", v.astype(np.float32).ravel())
        for obj in self.meshes:
            obj.data.update()
        self.cache = {f: v for f, v in self.cache.items() if f >= frame}  # t and t+1: the next frame's t-1 and t
        self.scene.frame_set(frame)


def _same_topology(a: tuple, b: tuple, n: int) -> bool:
    """Whether two evaluations of one mesh (world vertices, face-vertex indices, face sizes) share
    their topology and have the original mesh's ``n`` vertices (what the attributes index)."""
    return len(a[0]) == len(b[0]) == n and np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])


def write_geometry(path: str, meshes: list) -> None:
    """The world-space triangles of every rendered mesh at the current frame, as Cycles renders
    them (Blender's loop triangles of the evaluated mesh), with each triangle's object index:
    lfusd.truth.motion casts the visibility rays of exact occlusion against them.

    npz: ``vertices`` (N,3) float32 metres in lfusd's world, ``triangles`` (M,3) int32,
    ``instance`` (M,) int32; with --materials ``material`` (M,) int32, each triangle's flags (MaterialFlags)."""
    dg = bpy.context.evaluated_depsgraph_get()
    verts, tris, inst, flags, base = [], [], [], [], 0
    for obj in meshes:
        if obj.hide_render or not obj.visible_get():
            continue
        ev = obj.evaluated_get(dg)
        me = ev.to_mesh()
        me.calc_loop_triangles()
        co = np.empty(len(me.vertices) * 3, np.float64)
        me.vertices.foreach_get("co", co)
        t = np.empty(len(me.loop_triangles) * 3, np.int32)
        me.loop_triangles.foreach_get("vertices", t)
        m = np.array(ev.matrix_world, dtype=np.float64)
        if not len(t):
            ev.to_mesh_clear()
            continue
        verts.append((co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]).astype(np.float32))
        tris.append(t.reshape(-1, 3) + base)
        inst.append(np.full(len(t) // 3, obj.pass_index, np.int32))
        base += len(co) // 3
        if MATERIALS is not None:
            slot = np.empty(len(t) // 3, np.int32)
            me.loop_triangles.foreach_get("material_index", slot)
            per_slot = _slot_flags(obj)
            flags.append(per_slot[np.clip(slot, 0, len(per_slot) - 1)])
        ev.to_mesh_clear()
    cat = lambda parts, shape, dtype: np.concatenate(parts) if parts else np.zeros(shape, dtype)  # noqa: E731
    extra = {"material": cat(flags, (0,), np.int32)} if MATERIALS is not None else {}  # --materials: each triangle's flags
    atomic_write(path, lambda tmp: np.savez(tmp, vertices=cat(verts, (0, 3), np.float32), triangles=cat(tris, (0, 3), np.int32),
                                            instance=cat(inst, (0,), np.int32), **extra), suffix=".npz")


# --materials: what the first surface's material is, as flags (lfusd.keys TRANSMISSIVE, MIRROR, EMISSIVE)
# per material of Blender's scene (what the beauty renders), written on every mesh as a face attribute
# that the data material's AOV reads (exact per pixel: constant over a face), and per triangle into
# geometry.npz (the ray cast of depth_behind skips transmissive triangles).
MATERIAL_ATTRIBUTE = "lfusd_material_flags"
MIRROR_ROUGHNESS = 0.2  # mirror-like: roughness at most this, and metallic or specular at least MIRROR_REFLECT
MIRROR_REFLECT = 0.5
MATERIALS: dict | None = None  # material name -> flags, once mark_materials ran (None: --materials off)
_COMPONENT = {"Red": 0, "Green": 1, "Blue": 2, "R": 0, "G": 1, "B": 2, "X": 0, "Y": 1, "Z": 2}
_AFFINE = {"MULTIPLY_ADD": lambda a, b, c: a * b + c, "MULTIPLY": lambda a, b, c: a * b, "ADD": lambda a, b, c: a + b,
           "SUBTRACT": lambda a, b, c: a - b}


def _mean_value(sock, depth: int = 0) -> np.ndarray | None:
    """The mean over the surface of a shader input, (3,): its value, or what an image texture feeds it
    through channel splits and affine math (the importer's UsdUVTexture scale and bias; the mean of an
    affine map is the map of the mean). None where the chain holds anything else."""
    if not sock.is_linked:
        v = sock.default_value
        try:
            return np.resize(np.array(v[:3], np.float64), 3)
        except TypeError:
            return np.full(3, float(v))
    if depth > 8:
        return None
    link = sock.links[0]
    node, out = link.from_node, link.from_socket.name
    kind = node.bl_idname
    if kind == "ShaderNodeTexImage":
        image = node.image
        if image is None or tuple(image.size) == (0, 0):
            return None
        px = np.empty(len(image.pixels), np.float32)
        image.pixels.foreach_get(px)
        mean = px.reshape(-1, image.channels).mean(axis=0).astype(np.float64)
        return np.full(3, mean[3]) if out == "Alpha" and image.channels == 4 else np.resize(mean[:3], 3)
    if kind in ("ShaderNodeSeparateColor", "ShaderNodeSeparateXYZ", "ShaderNodeSeparateRGB"):
        c = _mean_value(node.inputs[0], depth + 1)
        return None if c is None or out not in _COMPONENT else np.full(3, c[_COMPONENT[out]])
    if kind in ("ShaderNodeMath", "ShaderNodeVectorMath") and node.operation in _AFFINE:
        args = [_mean_value(i, depth + 1) for i in list(node.inputs)[:3]]
        if any(a is None for a in args[:2]) or (node.operation == "MULTIPLY_ADD" and args[2] is None):
            return None
        return _AFFINE[node.operation](*args)
    return None


def _level(node, name: str, mat) -> float | None:
    """The mean of one input of ``node`` (0 where the node has no such input); None, with a warning, where unknown."""
    sock = node.inputs.get(name)
    if sock is None:
        return 0.0
    v = _mean_value(sock)
    if v is None:
        warn_once(f"material {mat.name}: lfusd cannot evaluate the {name} that its nodes compute; its masks take it as 0")
        return None
    return float(v.mean()) if name.endswith("Color") else float(v[0])


def material_flags(mat) -> int:
    """The flags of one material from its nodes: TRANSMISSIVE (a Principled BSDF with alpha below 1 or
    transmission above 0, a glass, transparent or refraction BSDF), MIRROR (a Principled BSDF with roughness
    at most MIRROR_ROUGHNESS and metallic or specular at least MIRROR_REFLECT, a glossy BSDF that smooth),
    EMISSIVE (emission strength and colour above 0)."""
    if mat is None or mat.node_tree is None:
        return 0
    flags = 0
    for node in mat.node_tree.nodes:
        kind = node.bl_idname
        if kind in ("ShaderNodeBsdfGlass", "ShaderNodeBsdfTransparent", "ShaderNodeBsdfRefraction"):
            flags |= TRANSMISSIVE
        elif kind in ("ShaderNodeBsdfGlossy", "ShaderNodeBsdfAnisotropic"):
            rough = _level(node, "Roughness", mat)
            if rough is not None and rough <= MIRROR_ROUGHNESS:
                flags |= MIRROR
        elif kind == "ShaderNodeEmission":
            if (_level(node, "Strength", mat) or 0.0) > 0 and (_level(node, "Color", mat) or 0.0) > 0:
                flags |= EMISSIVE
        elif kind == "ShaderNodeBsdfPrincipled":
            alpha, transmission = _level(node, "Alpha", mat), _level(node, "Transmission Weight", mat)
            if (alpha is not None and alpha < 1.0 - 1e-6) or (transmission or 0.0) > 0:
                flags |= TRANSMISSIVE
            rough = _level(node, "Roughness", mat)
            reflect = max(_level(node, "Metallic", mat) or 0.0, _level(node, "Specular IOR Level", mat) or 0.0)
            if rough is not None and rough <= MIRROR_ROUGHNESS and reflect >= MIRROR_REFLECT:
                flags |= MIRROR
            if (_level(node, "Emission Strength", mat) or 0.0) > 0 and (_level(node, "Emission Color", mat) or 0.0) > 0:
                flags |= EMISSIVE
    return flags


def _slot_flags(obj) -> np.ndarray:
    """Flags per material slot of ``obj`` (at least one entry: a mesh without materials is 0)."""
    return np.array([MATERIALS.get(s.material.name, 0) if s.material else 0 for s in obj.material_slots] or [0], np.int32)


def mark_materials(scene) -> None:
    """--materials: classify every material (MATERIALS) and give every mesh the face attribute
    MATERIAL_ATTRIBUTE (its faces' flags, by material slot) and the view layer the AOV that shows it."""
    global MATERIALS
    MATERIALS = {m.name: material_flags(m) for m in bpy.data.materials}
    for obj in scene.objects:
        if obj.type != "MESH":
            continue
        if obj.data.users > 1:  # attributes live on mesh data: give each object its own (its slots may differ)
            obj.data = obj.data.copy()
        mesh = obj.data
        slot = np.empty(len(mesh.polygons), np.int32)
        mesh.polygons.foreach_get("material_index", slot)
        per_slot = _slot_flags(obj)
        values = per_slot[np.clip(slot, 0, len(per_slot) - 1)].astype(np.float32)
        attr = mesh.attributes.get(MATERIAL_ATTRIBUTE) or mesh.attributes.new(MATERIAL_ATTRIBUTE, "FLOAT", "FACE")
        attr.data.foreach_set("value", values)
        mesh.update()
    vl = scene.view_layers[0]
    if MATERIAL_AOV.layer not in vl.aovs:
        aov = vl.aovs.add()
        aov.name, aov.type = MATERIAL_AOV.layer, "COLOR"


def _shift_lenses(scene, on: bool) -> None:
    w = scene.render.resolution_x  # with a horizontal sensor fit, lens shift is in image widths
    for view in scene.render.views:
        if not view.use:
            continue
        cam = bpy.data.objects[VIEW_PREFIX + view.camera_suffix].data
        cam.shift_x = -SAMPLE_OFFSET_PX[0] / w if on else 0.0
        cam.shift_y = -SAMPLE_OFFSET_PX[1] / w if on else 0.0


def _use_lens(scene, fstop: float, focus: float) -> None:
    """--fstop / --focus: every view's camera a thin lens (Cycles' depth of field, a round aperture of
    diameter lens / fstop, focused on the plane at planar depth ``focus`` metres); 0: a pinhole.
    A --lens view's OSL camera is its own thin lens (Lenses): Cycles' depth of field stays off there."""
    for view in scene.render.views:
        if not view.use:
            continue
        cam = bpy.data.objects[VIEW_PREFIX + view.camera_suffix].data
        dof = cam.dof
        dof.use_dof = fstop > 0 and cam.type != "CUSTOM"
        if fstop > 0:
            dof.focus_object = None
            dof.focus_distance = focus
            dof.aperture_fstop = fstop
            dof.aperture_blades = 0  # a disc


def compile_lens(name: str, source: str) -> tuple[str, str]:
    """(bytecode, digest) of the OSL camera ``source`` (lfusd.render.lens.osl_source), compiled with
    Cycles' compiler directly: bpy's module build lacks the ``oslquery`` module that Blender's own
    update of a custom camera imports (a shader without parameters needs no query)."""
    from cycles import osl

    text = bpy.data.texts.new(f"lfusd_lens_{name}.osl")
    text.write(source)
    errors = []
    ok, _, bytecode, digest = osl.update_internal_script(lambda kind, msg: errors.append(msg), text)
    if not ok or not bytecode:
        raise RuntimeError(f"the lens shader of camera {name} did not compile: {'; '.join(map(str, errors)) or 'see the log'}")
    return bytecode, digest


class Lenses:
    """--lens: each view's camera the OSL custom camera of its Brown-Conrady model (WorkUnit.lenses),
    compiled once per view for the beauty (samples about the pixel centre) and once for the data
    render (its one sample moved onto the pixel centre: the shader takes LENS_SAMPLE_OFFSET_PX off).
    With --fstop the beauty's shader is the thin lens of lfusd.render.lens; the data render's stays a
    pinhole through the lens centre."""

    def __init__(self, job: WorkUnit):
        from lfusd.camera import Distortion
        from lfusd.render.lens import osl_source

        self.code: dict[str, dict[bool, tuple[str, str]]] = {}
        for key, lens in job.lenses.items():
            dist, K = Distortion.from_dict(lens["dist"]), np.asarray(lens["K"], np.float64)
            cam = bpy.data.objects[f"{VIEW_PREFIX}_{key}"].data
            cam.type = "CUSTOM"
            cam.custom_mode = "INTERNAL"
            # --fstop: the beauty's thin lens, the aperture Cycles' own depth of field gives this camera
            # (radius lens / (2 fstop), lens in mm; lfusd's scene unit is the metre)
            radius = cam.lens * 1e-3 / (2.0 * job.fstop) if job.fstop > 0 else 0.0
            self.code[key] = {
                data: compile_lens(f"{key}_{'data' if data else 'beauty'}", osl_source(
                    dist, K, job.width, job.height, LENS_SAMPLE_OFFSET_PX if data else (0.0, 0.0),
                    0.0 if data else radius, 0.0 if data else job.focus))
                for data in (False, True)}
            _name_shader(cam, f"{key}_data")

    def use(self, data: bool) -> None:
        """Every distorted view's camera set for the data render (``data``) or the beauty."""
        for key, code in self.code.items():
            cam = bpy.data.objects[f"{VIEW_PREFIX}_{key}"].data
            cam.custom_bytecode, cam.custom_bytecode_hash = code[data]
            cam.update_tag()


def _name_shader(cam_data, name: str) -> None:
    try:
        cam_data.custom_shader = bpy.data.texts[f"lfusd_lens_{name}.osl"]  # Blender's update fails without oslquery
    except (ImportError, KeyError):
        pass


def distort_camera(cam_data, source: str) -> None:
    """Lens distortion: make one Blender camera the OSL custom camera of ``source``
    (lfusd.render.lens.osl_source), compiled here. bpy's module build lacks the ``oslquery`` module
    that Blender's own update of a custom camera imports, so the shader is compiled with Cycles'
    compiler directly and its bytecode stored on the camera (a shader without parameters needs no query)."""
    cam_data.type = "CUSTOM"
    cam_data.custom_mode = "INTERNAL"
    bytecode, digest = compile_lens(cam_data.name, source)
    _name_shader(cam_data, cam_data.name)
    cam_data.custom_bytecode = bytecode
    cam_data.custom_bytecode_hash = digest
    cam_data.update_tag()


def data_material(motion: bool, materials: bool = False):
    """The one material of the data render (a view-layer override): opaque black, with the t+/-1
    position AOVs when ``motion`` and the first surface's material flags (MaterialFlags) when ``materials``.

    No data pass depends on a surface's shading, so the scene's own materials (textures, BSDF
    layers, transparency chains) need not be evaluated: measured, a quarter less CPU time for the
    data render (2.0 -> 1.5 s for 9 views at 512x512). Normals are then the mesh's interpolated
    shading normals, without normal or bump maps (docs/CONVENTIONS.md). An opaque surface also ends
    the camera ray at the first surface, which is the surface every data pass records
    (pass_alpha_threshold 0)."""
    mat = bpy.data.materials.new("lfusd_data")
    if mat.node_tree is None:  # Blender 5.0 gives new materials a node tree (use_nodes is deprecated)
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new("ShaderNodeOutputMaterial")
    black = nodes.new("ShaderNodeEmission")
    black.inputs["Strength"].default_value = 0.0
    links.new(black.outputs["Emission"], out.inputs["Surface"])
    for key, aov_name in NEIGHBOUR_AOVS.items() if motion else ():
        attr = nodes.new("ShaderNodeAttribute")
        attr.attribute_type, attr.attribute_name = "GEOMETRY", f"lfusd_{key}"
        aov = nodes.new("ShaderNodeOutputAOV")
        aov.aov_name = aov_name
        links.new(attr.outputs["Vector"], aov.inputs["Color"])
    if materials:  # the face attribute of MaterialFlags: constant per face, so exact at the pixel centre
        attr = nodes.new("ShaderNodeAttribute")
        attr.attribute_type, attr.attribute_name = "GEOMETRY", MATERIAL_ATTRIBUTE
        aov = nodes.new("ShaderNodeOutputAOV")
        aov.aov_name = MATERIAL_AOV.layer
        links.new(attr.outputs["Fac"], aov.inputs["Color"])
    return mat


class Lighting:
    """What the data render leaves out and the beauty needs: lights, world and the scene's own
    materials (replaced by :func:`data_material`).

    No data pass depends on light; with lights and world gone Cycles traces no shadow rays and
    samples no light at the first hit (measured: 0.97 -> 0.55 s of CPU for 3 views at 512x512)."""

    def __init__(self, scene, motion: bool, materials: bool = False):
        self.scene, self.world = scene, scene.world
        self.lights = [o for o in scene.objects if o.type == "LIGHT" and not o.hide_render]
        self.material = data_material(motion, materials)

    def set(self, on: bool) -> None:
        for o in self.lights:
            o.hide_render = not on
        self.scene.world = self.world if on else None
        self.scene.view_layers[0].material_override = None if on else self.material


class CyclesClock:
    """Splits the CPU time of each render call by what Cycles reports doing (its status lines, as
    the render_stats handler receives them): scene sync (Blender's export and Cycles' scene and BVH
    updates), path tracing ("Sample ..."), and writing the files once Cycles has finished. Charged
    to lfusd.cpu_account as "<render> sync", "<render> trace" and "<render> write"."""

    TRACE = ("Sample", "Rendered", "Path Tracing", "Denoising")
    WRITE = ("Finished", "Time:")

    def __init__(self):
        self.render, self.state, self.mark = "", "sync", 0.0
        bpy.app.handlers.render_stats.append(self._stats)

    def _charge(self) -> None:
        now = time.process_time()
        cpu_account.add(f"{self.render} {self.state}", now - self.mark)
        self.mark = now

    def _stats(self, text, *_):
        text = str(text)
        state = "trace" if any(w in text for w in self.TRACE) else "write" if any(w in text for w in self.WRITE) else "sync"
        if state != self.state:
            self._charge()
            self.state = state

    def call(self, render: str, scene, filepath: str) -> None:
        """One render call (all enabled views), its CPU time split by phase."""
        self.render, self.state, self.mark = render, "sync", time.process_time()
        scene.render.filepath = filepath
        bpy.ops.render.render(write_still=True)
        self.state = "write" if self.state != "sync" else self.state
        self._charge()


_CLOCK: CyclesClock | None = None
_LENSES: Lenses | None = None  # --lens: the views' OSL cameras (set by main)


def _render(scene, filepath: str, render: str) -> None:
    global _CLOCK
    _CLOCK = _CLOCK or CyclesClock()
    _CLOCK.call(render, scene, filepath)


def _use_views(scene, chunk: list[str]) -> None:
    wanted = set(chunk)
    for v in scene.render.views:
        v.use = v.name in wanted
    # multiview finds each view's camera from the scene camera's name: keep it one of the chunk's
    scene.camera = bpy.data.objects[VIEW_PREFIX + chunk[0]]


def render_chunk(scene, job: WorkUnit, scratch: str, lighting: Lighting, phases: dict) -> None:
    """The beauty and data renders of the enabled views (one multiview call each)."""
    # Beauty: linear RGB, user samples, default filter (not for a repair that needs the raw passes alone).
    if job.beauty:  # its phase is logged only when it is rendered (tests count repairs by it)
        t, c = time.perf_counter(), time.process_time()
        _render_beauty(scene, job, scratch, lighting)
        phases["beauty"] = phases.get("beauty", 0.0) + time.perf_counter() - t
        phases["beauty_cpu"] = phases.get("beauty_cpu", 0.0) + time.process_time() - c
    _render_data(scene, job, scratch, lighting, phases)


def _render_beauty(scene, job: WorkUnit, scratch: str, lighting: Lighting) -> None:
    """The beauty: linear RGB, the user's samples, Blender's default filter."""
    vl = scene.view_layers[0]
    cyc = scene.cycles
    im = scene.render.image_settings
    lighting.set(True)
    for switch in PASS_SWITCHES:  # the data passes (lfusd.keys.RAW_PASSES) off
        setattr(vl, switch, False)
    vl.use_pass_combined = True
    cyc.samples = job.samples
    cyc.pixel_filter_type = "BLACKMAN_HARRIS"
    cyc.filter_width = 1.5
    cyc.max_bounces = 12  # Blender's default
    im.media_type = "IMAGE"
    im.file_format = "OPEN_EXR"
    im.color_mode = "RGB"
    im.color_depth = "16"
    im.exr_codec = "ZIP"
    _shift_lenses(scene, False)
    # --shutter: Cycles' motion blur, centred on the frame, in the beauty only (the data render turns it off)
    scene.render.use_motion_blur = job.shutter > 0
    if job.shutter > 0:
        scene.render.motion_blur_shutter = job.shutter
        scene.render.motion_blur_position = "CENTER"
    _use_lens(scene, job.fstop, job.focus)
    if _LENSES is not None:
        _LENSES.use(data=False)
    _render(scene, os.path.join(scratch, "rgb"), "beauty")


def _render_data(scene, job: WorkUnit, scratch: str, lighting: Lighting, phases: dict) -> None:
    """The data passes: one sample at each pixel centre, no bounces, no light."""
    vl = scene.view_layers[0]
    cyc = scene.cycles
    im = scene.render.image_settings
    t, c = time.perf_counter(), time.process_time()
    lighting.set(False)
    for switch in PASS_SWITCHES:  # every render pass of lfusd.keys.RAW_PASSES
        setattr(vl, switch, True)
    vl.use_pass_combined = False
    cyc.samples = 1
    cyc.pixel_filter_type = "BOX"
    cyc.filter_width = 0.01
    cyc.max_bounces = 0
    im.media_type = "MULTI_LAYER_IMAGE"
    im.color_depth = "32"
    im.exr_codec = job.raw_codec
    # one part holding every pass, not a part per pass: half Blender's CPU time writing them
    # (measured on the default scene at 1024x1024, uncompressed: 0.14-0.16 -> 0.05-0.06 core-s per view)
    im.use_exr_interleave = True
    _shift_lenses(scene, True)
    scene.render.use_motion_blur = False  # every data pass at the frame's instant (Cycles' vector pass needs it off too)
    _use_lens(scene, 0.0, 0.0)  # and through the lens centre
    if _LENSES is not None:
        _LENSES.use(data=True)
    _render(scene, os.path.join(scratch, "passes"), "data")
    phases["data"] = phases.get("data", 0.0) + time.perf_counter() - t
    phases["data_cpu"] = phases.get("data_cpu", 0.0) + time.process_time() - c


def render_frame(scene, job: WorkUnit, frame: int, suffixes: list[str], motion: MotionAttributes | None, lighting: Lighting) -> None:
    """Render one frame's views chunk by chunk, handing each chunk's files to the parent as it is done."""
    t = time.perf_counter()
    with cpu_account.phase("scene"):
        if motion is not None:
            motion.set_frame(frame)
        else:
            scene.frame_set(frame)
    phases = {"scene": time.perf_counter() - t}
    geometry = None
    if motion is not None:  # the frame's triangles, for exact occlusion: written once, linked into each chunk
        tg = time.perf_counter()
        os.makedirs(job.scratch, exist_ok=True)
        # beside the chunk folders, not in one: the parent removes a chunk's folder once it is committed
        geometry = os.path.join(job.scratch, f"geometry_f{frame:06d}.npz")
        with cpu_account.phase("geometry"):
            write_geometry(geometry, motion.meshes)
        phases["geometry"] = time.perf_counter() - tg
    for k, chunk in enumerate(view_chunks(suffixes, job.width, job.height, job.render_pixels)):
        scratch = os.path.join(job.scratch, f"f{frame:06d}_c{k:03d}")
        os.makedirs(scratch, exist_ok=True)
        if geometry is not None:
            link_or_copy(geometry, os.path.join(scratch, "geometry.npz"))
        _use_views(scene, chunk)
        render_chunk(scene, job, scratch, lighting, phases)
        print(f"lfusd: frame {frame} views {len(chunk)} seconds " + " ".join(f"{k} {v:.3f}" for k, v in phases.items()), file=sys.stderr, flush=True)
        cpu_account.flush("worker")
        emit("frame", frame=frame, scratch=scratch, views=[s[1:] for s in chunk], seconds=time.perf_counter() - t,
             phases={k: round(v, 4) for k, v in phases.items()}, evaluations=motion.evaluations if motion is not None else 0)
    if geometry is not None:
        os.unlink(geometry)  # each chunk holds its own link


def _test_kill_hook(frame: int) -> None:
    # Tests simulate a worker killed mid-run (SIGKILL: no clean-up) after a given frame.
    if os.environ.get("LFUSD_TEST_KILL_AFTER_FRAME") == str(frame):
        os.kill(os.getpid(), 9)
    # Tests that kill a whole Ray node mid-unit slow that node's worker down, so that the kill
    # lands after its first frame and before its last (a tiny frame renders in a fraction of a second).
    delay = os.environ.get("LFUSD_TEST_FRAME_DELAY")
    if delay:
        time.sleep(float(delay))


def main() -> int:
    parent = int(os.environ.get(PARENT_PID_ENV, "0"))
    if parent:  # a killed lfusd must leave no Blender rendering on
        die_with_parent(parent)
    job = WorkUnit.from_json(json.loads(sys.stdin.read()))
    try:
        t0 = time.time()
        bpy.utils.register_class(_ImportCheckHook)
        with CapturedOutput() as captured:
            import_stage(job.stage, job.has_dome, job.world)
        warn_import(captured.text)
        fallback_surfaces()
        warn_missing_images()
        if job.add_light:
            add_neutral_light(bpy.context.scene)
        if job.physical_sky:
            use_physical_sky(bpy.context.scene)
        scene, suffixes = setup_scene(job)
        realize_instances(scene, job)
        # --lens: the OSL camera is checked against OpenCV on the CPU only (tests/render/test_lens_render.py)
        device = select_device(scene, "cpu" if job.lenses else job.device)
        motion = MotionAttributes(scene, *job.stage_range) if job.motion else None
        cpu_account.startup()
        emit("ready", device=device, seconds=time.time() - t0)
        if job.materials:
            mark_materials(scene)
        lighting = Lighting(scene, motion is not None, job.materials)
        if job.lenses:
            global _LENSES
            _LENSES = Lenses(job)
        for frame in job.frames:
            render_frame(scene, job, frame, suffixes, motion, lighting)
            _test_kill_hook(frame)
    except Exception as e:  # the parent turns this into a one-line error
        emit("error", message=f"{type(e).__name__}: {e}", trace=traceback.format_exc())
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
