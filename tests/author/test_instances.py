"""Instances are objects: scenegraph instances and (nested) PointInstancer instances in the object
table, poses, verify's geometry and object_ids_for, against the authored placements."""

from types import SimpleNamespace

import numpy as np

from lfusd.author.geometry import StageGeometry
from lfusd.author.labels import ObjectPoses, object_prim, object_table
from lfusd.truth.verify import object_ids_for
from tests.support.instances import CROWN, PINE, PINES, TREES, TRUNK, expected_objects, write_instances_stage


def _stage(tmp_path):
    return write_instances_stage(tmp_path / "inst.usda")


def test_every_instance_is_an_object_with_its_path_label_and_pose(tmp_path):
    stage = _stage(tmp_path)
    objects, classes = object_table(stage)
    expected = expected_objects()
    assert [o.prim_path for o in objects] == sorted(expected)  # path order (indices < 10 here)
    assert [o.instance_id for o in objects] == list(range(1, len(expected) + 1))
    assert {o.prim_path: o.label for o in objects} == {p: lab for p, (lab, _) in expected.items()}
    assert all(classes[o.class_id] == o.label for o in objects)
    by_path = {o.prim_path: o for o in objects}
    assert by_path["/World/Forest/Tree_1"].mesh_paths == ("/World/Forest/Tree_1/Crown", "/World/Forest/Tree_1/Trunk")
    assert by_path["/World/Forest/Trees[2]"].mesh_paths == ("/World/Forest/Trees[2]/Body",)
    # Deterministic: a second walk gives the same table.
    assert object_table(stage)[0] == objects
    poses = ObjectPoses(stage)
    for f in (1, 2, 3):
        got = poses.at(list(expected), f)
        for path, (_, t) in expected.items():
            want = np.eye(4)
            want[:3, 3] = t(f)
            np.testing.assert_allclose(got[path], want, atol=1e-6, err_msg=f"{path} at frame {f}")
    assert object_prim(stage, "/World/Forest/Trees[1]/Cones[0]").GetPath() == "/World/Forest/Trees/Protos/Pine/Cones"


def test_geometry_places_every_instance_and_object_ids_follow_paths(tmp_path):
    stage = _stage(tmp_path)
    objects, _ = object_table(stage)
    geo = StageGeometry(stage)
    expected = expected_objects()
    for f in (1, 3):
        meshes = {m.prim_path: m for m in geo.meshes(f)}
        for tree, pos in TREES.items():
            for name, (centre, edge) in (("Trunk", TRUNK), ("Crown", CROWN)):
                v = meshes[f"{tree}/{name}"].vertices
                np.testing.assert_allclose(v.mean(0), pos(f) + centre, atol=1e-6)
                np.testing.assert_allclose(v.max(0) - v.min(0), edge, atol=1e-6)
        for i, pos in enumerate(PINES):
            np.testing.assert_allclose(meshes[f"/World/Forest/Trees[{i}]/Body"].vertices.mean(0), pos(f) + PINE[0], atol=1e-6)
        for path, (label, t) in expected.items():
            if label in ("bush", "cone"):  # boxes centred on their instance
                np.testing.assert_allclose(meshes[path].vertices.mean(0), t(f), atol=1e-6)
    ids = object_ids_for([m.prim_path for m in geo.meshes(1)], {o.instance_id: SimpleNamespace(prim_path=o.prim_path) for o in objects})
    id_of = {o.prim_path: o.instance_id for o in objects}
    want = [id_of[p.owner] for p in geo.parts] + [0]
    assert ids.tolist() == want
    assert len(set(ids[:-1].tolist())) == len(objects)  # every object owns at least one mesh, ids distinct


def test_object_ids_for_resolves_point_instance_paths_to_the_nearest_object():
    objects = {1: SimpleNamespace(prim_path="/A[1]"), 2: SimpleNamespace(prim_path="/A[1]/B[2]"), 3: SimpleNamespace(prim_path="/A[10]"),
               4: SimpleNamespace(prim_path="/World/Car")}
    paths = ["/A[1]/Body", "/A[1]/B[2]", "/A[1]/B[2]/Leaf", "/A[10]/Body", "/A[1]/B[3]", "/World/Car/Wheel", "/World/Carrot", "/A[2]"]
    assert object_ids_for(paths, objects).tolist() == [1, 2, 2, 3, 1, 4, 0, 0, 0]
