"""Blender side of the skinning test: import a stage and dump meshes' evaluated world vertices.

Usage: python blender_skin_probe.py STAGE MESH_NAME[,MESH_NAME...] FIRST LAST OUT.npz
Writes one array (frames, vertices, 3) of world positions per mesh name (Blender object names
are prim leaf names, so give each probed mesh a unique leaf name); runs in its own process
because Blender's bundled USD must not meet usd-core's pxr.
"""

import sys

import bpy

bpy.utils.expose_bundled_modules()

import numpy as np  # noqa: E402


def main():
    stage, mesh_names, first, last, out = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=stage, import_skeletons=True, set_frame_range=True)
    scene = bpy.context.scene
    result = {}
    for mesh_name in mesh_names.split(","):
        objs = [o for o in scene.objects if o.type == "MESH" and o.name.split(".")[0] == mesh_name]
        if len(objs) != 1:
            raise SystemExit(f"expected one mesh named {mesh_name}, found {[o.name for o in scene.objects]}")
        obj = objs[0]
        frames = []
        for f in range(first, last + 1):
            scene.frame_set(f)
            dg = bpy.context.evaluated_depsgraph_get()
            ev = obj.evaluated_get(dg)
            me = ev.to_mesh()
            co = np.empty(len(me.vertices) * 3, dtype=np.float64)
            me.vertices.foreach_get("co", co)
            m = np.array(ev.matrix_world, dtype=np.float64)
            frames.append(co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3])
            ev.to_mesh_clear()
        result[mesh_name] = np.array(frames)
        print(mesh_name, "modifiers:", [md.type for md in obj.modifiers])
    np.savez(out, **result)


main()
