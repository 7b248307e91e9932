"""Lens distortion in Cycles (issue 40 item 4): the OSL custom camera of lfusd.render.lens renders
every pass at the distorted pixel's own ray, checked against OpenCV's projectPoints and closed-form casts."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np
import pytest

from lfusd.camera import Camera, Distortion, RigSpec, pixel_grid
from lfusd.data.passes import read_exr
from lfusd.render.lens import osl_source, planar_depth
from lfusd.truth.lens import cast_geometry

pytestmark = pytest.mark.render

W, H = 40, 30
DIST = Distortion(k1=-0.25, k2=0.05, p1=0.003, p2=-0.004, k3=0.002)

PROBE = """
import sys, json
import bpy, mathutils
import numpy as np
from lfusd.render.worker import distort_camera
W, H, out, source = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], open(sys.argv[4]).read()
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.device = "CPU"
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = W, H, 100
scene.cycles.samples = 1  # the data render's one sample at the pixel centre
scene.cycles.pixel_filter_type = "BOX"
scene.cycles.filter_width = 0.01
scene.cycles.use_denoising = False
bpy.ops.mesh.primitive_plane_add(size=20, location=(0, 0, 0))
bpy.context.object.pass_index = 1
bpy.ops.mesh.primitive_cube_add(size=0.6, location=(0.0, 0.0, 0.3))
bpy.context.object.pass_index = 2
cam_data = bpy.data.cameras.new("lens")
cam = bpy.data.objects.new("lens", cam_data)
scene.collection.objects.link(cam)
scene.camera = cam
cam.location = (0.4, -3.0, 1.3)
cam.rotation_euler = (mathutils.Vector((0.0, 0.0, -0.4)) - cam.location).to_track_quat("-Z", "Y").to_euler()
cam_data.sensor_fit, cam_data.sensor_width, cam_data.lens = "HORIZONTAL", 36.0, 39.0
distort_camera(cam_data, source)
vl = scene.view_layers[0]
vl.use_pass_position = vl.use_pass_z = vl.use_pass_object_index = True
im = scene.render.image_settings
im.media_type = "MULTI_LAYER_IMAGE"
im.file_format = "OPEN_EXR_MULTILAYER"
im.color_depth = "32"
scene.render.filepath = out
bpy.ops.render.render(write_still=True)
print("PROBE" + json.dumps(np.array(cam.matrix_world).tolist()))
"""


@pytest.fixture(scope="module")
def lens_render(tmp_path_factory):
    d = tmp_path_factory.mktemp("lens")
    K = RigSpec(width=W, height=H).intrinsics()
    (d / "probe.py").write_text(PROBE)
    (d / "lens.osl").write_text(osl_source(DIST, K, W, H))
    out = subprocess.run([sys.executable, str(d / "probe.py"), str(W), str(H), str(d / "out.exr"), str(d / "lens.osl")],
                         capture_output=True, text=True, check=True).stdout
    blender_pose = np.array(json.loads(next(ln for ln in out.splitlines() if ln.startswith("PROBE"))[5:]))
    cam = Camera(K, blender_pose @ np.diag([1.0, -1.0, -1.0, 1.0]))  # Blender's camera (y up, -z forward) -> OpenCV
    passes = read_exr(d / "out.exr")
    return cam, passes


def _opencv(points, cam):
    R, C = cam.world_to_cam()
    rvec, _ = cv2.Rodrigues(R)
    uv, _ = cv2.projectPoints(points.reshape(-1, 1, 3), rvec, -R @ C, np.asarray(cam.K, np.float64), DIST.coeffs)
    return uv.reshape(*points.shape[:-1], 2)


def test_every_pixel_sees_the_point_opencv_images_there(lens_render):
    cam, passes = lens_render
    position = np.stack([passes[f"ViewLayer.Position.{c}"] for c in "XYZ"], -1).astype(np.float64)
    u, v = pixel_grid(H, W, np.float64)
    err = np.hypot(*np.moveaxis(_opencv(position, cam) - np.stack([u, v], -1), -1, 0))
    assert err.max() < 0.01, err.max()


def test_depth_and_instance_equal_casts_of_the_distorted_rays(lens_render):
    cam, passes = lens_render
    plane = np.array([[-10, -10, 0], [10, -10, 0], [10, 10, 0], [-10, 10, 0]], np.float32)
    box = np.array([[x, y, z] for z in (0, 0.6) for y in (-0.3, 0.3) for x in (-0.3, 0.3)], np.float32)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = np.array([[0, 1, 2], [0, 2, 3]] + [[4 + q[0], 4 + q[i], 4 + q[i + 1]] for q in quads for i in (1, 2)], np.int32)
    cast = cast_geometry(np.concatenate([plane, box]), tris, np.array([1, 1] + [2] * 12, np.int32), cam, DIST, W, H)
    depth = planar_depth(passes["ViewLayer.Depth.Z"], DIST, cam.K)
    instance = np.rint(passes["ViewLayer.Object Index.X"]).astype(np.int32)
    position = np.stack([passes[f"ViewLayer.Position.{c}"] for c in "XYZ"], -1).astype(np.float64)
    # away from the box's silhouette (a sample 0.005 px off the centre may cross it), each pixel is the cast's
    edge = np.zeros((H, W), bool)
    boundary = cast["instance"] == 2
    edge[:-1] |= boundary[:-1] != boundary[1:]
    edge[1:] |= boundary[:-1] != boundary[1:]
    edge[:, :-1] |= boundary[:, :-1] != boundary[:, 1:]
    edge[:, 1:] |= boundary[:, :-1] != boundary[:, 1:]
    assert (instance[~edge] == cast["instance"][~edge]).all() and (cast["instance"] == 2).sum() > 20
    assert np.abs(depth[~edge] / cast["depth"][~edge] - 1).max() < 1e-4
    R, C = cam.world_to_cam()
    assert np.abs(depth / ((position - C) @ R[2]) - 1).max() < 1e-4  # planar, not the ray distance Cycles writes
