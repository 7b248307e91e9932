"""A walking (UsdSkel) person rendered with `lfusd render-video`: its flow against motion traced
independently (pxr skinning + Open3D ray casts, lfusd.truth.verify.trace_motion), and `lfusd verify`."""

from __future__ import annotations

import numpy as np
import pytest
from pxr import UsdGeom

from lfusd import Dataset
from lfusd.author.people import add_person
from lfusd.cli import main
from lfusd.camera import RigSpec
from lfusd.author.scenes.build import Builder, box
from lfusd.author.stage import new_stage
from lfusd.author.rigs import add_rig
from lfusd.truth.verify import trace_motion

pytestmark = pytest.mark.render

FIRST, LAST = 20, 22  # mid-walk: the person set off at frame 1 and is at full speed by frame 16
# Seen at 45 degrees from 2.3 m, the person fills most of the image height (its interior survives the
# 2 px edge margin).
RIG = RigSpec(name="main", rows=1, cols=2, width=128, height=128, baseline=0.1, at=(0.55, -1.85, 1.0), look_at=(-0.75, 0.0, 0.88))


@pytest.fixture(scope="module")
def walked(tmp_path_factory):
    root = tmp_path_factory.mktemp("person")
    path = root / "walk.usda"
    stage = new_stage(path, 1, 30)
    UsdGeom.Scope.Define(stage, "/World/Looks")
    UsdGeom.Xform.Define(stage, "/World/Lights")
    b = Builder(stage, path)
    b.obj("/World/Ground", "ground")
    b.mesh("/World/Ground/surface", box((20.0, 20.0, 0.2), (0.0, 0.0, -0.1), tile=2.0), "grass")
    b.sun(30.0, 50.0, 1.0)
    b.dome(0.5)
    person = add_person(stage, [(-1.5, 0.0), (4.0, 0.0)], gait="walk", speed=1.3)
    add_rig(stage, RIG)
    stage.GetRootLayer().Save()
    out = root / "out"
    assert main(["render-video", str(path), "-o", str(out), "--frames", f"{FIRST}-{LAST}", "--samples", "1",
                 "--quiet", "--device", "cpu"]) == 0
    return stage, str(person.GetPath()), out


def test_walking_person_flow_matches_traced_motion(walked):
    stage, person, out = walked
    ds = Dataset(out)
    ids = [i for i, o in ds.objects.items() if o.prim_path == person]
    assert len(ids) == 1
    errs, moved = [], []
    for frame in (FIRST, FIRST + 1):
        for view in ds.views:
            K = ds.intrinsics(view)
            tr = trace_motion(stage, frame, K, ds.cam_to_world(frame, view), ds.cam_to_world(frame + 1, view),
                              RIG.height, RIG.width)
            inst = ds.read(frame, view, "instance")
            mine = np.array([p.startswith(person + "/") for p in tr["prim_paths"]] + [False])
            traced_person = mine[tr["mesh"]]  # mesh index -1 (background) picks the trailing False
            sel = (inst == ids[0]) & traced_person & tr["valid"] & ~tr["occluded"] & ds.read(frame, view, "valid_fwd")
            # away from the silhouette by one pixel (a ray grazing it may hit the ground in the other tracer)
            other = np.pad(inst != ids[0], 1, constant_values=True)
            sel &= ~(other[1:-1, 1:-1] | other[:-2, 1:-1] | other[2:, 1:-1] | other[1:-1, :-2] | other[1:-1, 2:])
            assert sel.sum() >= 40, (frame, view, int(sel.sum()))
            flow = ds.read(frame, view, "flow_fwd")
            errs.append(np.linalg.norm(flow[sel] - tr["flow"][sel], axis=-1))
            moved.append(np.linalg.norm(tr["flow"][sel], axis=-1))
    err, moved = np.concatenate(errs), np.concatenate(moved)
    assert np.median(moved) > 0.5  # the person really walks across the image (pixels per frame)
    assert np.median(err) < 0.01 and np.percentile(err, 99) < 0.05, (np.median(err), np.percentile(err, 99))


def test_lfusd_verify_accepts_the_walking_persons_depth_flow_and_scene_flow(walked):
    from lfusd.truth.verify import verify_dataset

    _, _, out = walked
    report = verify_dataset(Dataset(out))  # every pixel, occlusion included, default limits
    assert report.ok, report.failures()
    # At tiny sizes only the occlusion masks may disagree, on the person's 1 px silhouette.
    assert all(line.startswith(("occlusion_fwd", "occlusion_bwd")) for line in report.failures()), report.failures()


def test_lfusd_verify_exits_0_on_the_walking_person(walked, capsys):
    """At 128 px the silhouette is a small share of the person; at 64 px occlusion disagrees on ~2%."""
    _, _, out = walked
    assert main(["verify", str(out)]) == 0
