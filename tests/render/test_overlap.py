"""render-video's pipeline: views rendered in chunks, motion derived while rendering goes on."""

from __future__ import annotations

import logging
import re
import shutil

import numpy as np
import pytest
from support.scenes import write_motion_stage

from lfusd import Dataset
from lfusd.camera import RigSpec
from lfusd.data import integrity
from lfusd.layout import MOTION_FILE, view_key
from lfusd.render import plan
from lfusd.render.job import render_video
from lfusd.render.overlap import MotionScheduler
from lfusd.render.request import RenderRequest

RIG = RigSpec(name="main", rows=2, cols=2, width=40, height=32, baseline=0.1, at=(0.3, -5.0, 1.8), look_at=(0.0, 0.5, 0.6))
FRAMES = [1, 2, 3]
FRAME_EVENT = re.compile(r"rig main frame (\d+): (\d+) views in .* scene evaluated at (\d+) times so far")


def test_view_chunks_keep_each_render_call_within_the_pixel_budget():
    views = [f"_{i:02d}" for i in range(81)]
    for (w, h), budget in (((1024, 1024), 16 << 20), ((512, 512), 16 << 20), ((4096, 4096), 16 << 20), ((64, 48), 64 * 48 * 5)):
        got = plan.view_chunks(views, w, h, budget)
        assert [v for c in got for v in c] == views  # every view once, in order
        per_call = max(1, budget // (w * h))
        assert max(len(c) for c in got) <= per_call
        assert len(got) == -(-81 // per_call)  # no more calls than the budget needs
        assert max(len(c) for c in got) - min(len(c) for c in got) <= 1


def _render(root, name, caplog) -> tuple[Dataset, list[tuple[int, int, int]]]:
    with caplog.at_level(logging.DEBUG, logger="lfusd.render.executors"):
        caplog.clear()
        # raw passes kept: the scheduler test derives the motion again from them
        result = render_video(RenderRequest(stage=root / "movers.usda", out=root / name, samples=1, device="cpu", quiet=True, keep_raw=True))
        events = [tuple(map(int, m.groups())) for r in caplog.records if (m := FRAME_EVENT.search(r.getMessage()))]
    assert result.derived == len(FRAMES) * len(RIG.views)
    return Dataset(root / name), events


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    root = tmp_path_factory.mktemp("overlap")
    write_motion_stage(root / "movers.usda", RIG, len(FRAMES))
    return root


@pytest.mark.render
def test_chunked_views_give_the_same_ground_truth_as_one_call(renders, caplog, monkeypatch):
    whole, events = _render(renders, "whole", caplog)
    assert sorted(n for _, n, _ in events) == [4] * len(FRAMES)  # one call per frame holds all 4 views
    monkeypatch.setattr(plan, "RENDER_PIXELS", 2 * RIG.width * RIG.height - 1)  # room for one view per call
    chunked, events = _render(renders, "chunked", caplog)
    assert sorted(n for _, n, _ in events) == [1] * len(FRAMES) * len(RIG.views)
    compared = 0
    for f in FRAMES:
        for v in RIG.views:
            a, b = whole.read(f, v, "depth"), chunked.read(f, v, "depth")
            fg = np.isfinite(a)
            assert fg.sum() > 100 and np.array_equal(fg, np.isfinite(b))
            np.testing.assert_allclose(b[fg], a[fg], rtol=1e-5)  # verify holds depth to 1e-4 relative
            assert (whole.read(f, v, "instance") == chunked.read(f, v, "instance")).mean() >= 0.999
            for d in ("fwd", "bwd"):
                valid = whole.read(f, v, f"valid_{d}")
                assert np.array_equal(valid, chunked.read(f, v, f"valid_{d}"))
                err = np.linalg.norm(whole.read(f, v, f"flow_{d}")[valid] - chunked.read(f, v, f"flow_{d}")[valid], axis=-1)
                assert err.size == 0 or err.max() < 0.01  # verify's limit is 0.05 px
                compared += int(valid.sum())
            sf = np.linalg.norm(whole.read(f, v, "scene_flow") - chunked.read(f, v, "scene_flow"), axis=-1)
            assert np.nanmax(np.where(whole.read(f, v, "valid_fwd"), sf, 0.0)) < 1e-4
    assert compared > 5000, compared  # pixels with motion compared


@pytest.mark.render
def test_motion_derived_during_rendering_is_complete_and_current(renders, caplog):
    out = renders / "whole"
    if not (out / "manifest.json").is_file():
        _render(renders, "whole", caplog)
    checked, problems = integrity.check_dataset(out)
    assert checked == len(FRAMES) * len(RIG.views) and not problems, problems


@pytest.mark.render
def test_scheduler_derives_a_frame_as_soon_as_its_neighbours_are_committed(renders, caplog, tmp_path):
    """Views reported committed frame by frame, as the executors do: frame t is derived once t-1,
    t and t+1 are in, and the result equals the derivation after rendering (derive_dataset)."""
    src = renders / "whole"
    if not (src / "manifest.json").is_file():
        _render(renders, "whole", caplog)
    out = tmp_path / "ds"
    shutil.copytree(src, out)
    for p in out.glob("main/f*/*/" + MOTION_FILE):
        p.unlink()
    keys = {v: view_key(v) for v in RIG.views}
    todo = {("main", f, v) for f in FRAMES for v in RIG.views}
    sched = MotionScheduler(out, {"main": (list(RIG.views), (RIG.width, RIG.height))}, FRAMES, FRAMES, todo, lanes=2)
    try:
        for f in FRAMES:
            for v in RIG.views:
                sched.committed("main", f, keys[v])
            [fut.result() for fut in sched.futures]
            derived = {g for g in FRAMES for v in RIG.views if (out / "main" / f"f{g:06d}" / keys[v] / MOTION_FILE).is_file()}
            assert derived == {g for g in FRAMES if g < f or g == FRAMES[-1] == f}, (f, derived)  # t waits for t+1
        written, left = sched.finish()
    finally:
        sched.stop()
    assert written == len(FRAMES) * len(RIG.views) and left == {}
    assert integrity.check_dataset(out) == (len(FRAMES) * len(RIG.views), [])
    a, b = Dataset(out), Dataset(src)
    for f in FRAMES:
        for v in RIG.views:
            for key in ("flow_fwd", "flow_bwd", "valid_fwd", "occlusion_bwd"):
                np.testing.assert_array_equal(a.read(f, v, key), b.read(f, v, key))


@pytest.mark.render
def test_the_scene_is_evaluated_once_per_neighbour_frame(renders, caplog):
    """Frame t needs the vertices at t-1 and t+1; t-1 was frame t-2's t+1: each time is evaluated once."""
    _, events = _render(renders, "evaluations", caplog)
    needed = {g for f in FRAMES for g in (f - 1, f + 1) if g in FRAMES}  # the stage holds frames 1-3 only
    assert max(e for _, _, e in events) == len(needed)


def test_derivation_lanes_take_the_cores_a_gpu_render_leaves_within_memory():
    from lfusd.render.overlap import LANE_BYTES, derivation_lanes

    gib = 1 << 30
    # the CPU renders: one lane per Blender worker, whatever the machine
    assert derivation_lanes(1, "cpu", 81, cores=16, memory=128 * gib) == 1
    assert derivation_lanes(3, "cpu", 81, cores=16, memory=128 * gib) == 3
    # a GPU: the cores the workers and the parent leave
    for device in ("cuda", "optix"):
        assert derivation_lanes(1, device, 81, cores=16, memory=128 * gib) == 14
    assert derivation_lanes(2, "optix", 81, cores=16, memory=128 * gib) == 13
    # at most a lane per view of a frame, per LANE_BYTES of half the memory, never fewer than the workers
    assert derivation_lanes(1, "optix", 9, cores=64, memory=512 * gib) == 9
    assert derivation_lanes(1, "optix", 81, cores=64, memory=8 * LANE_BYTES) == 4
    assert derivation_lanes(1, "optix", 81, cores=2, memory=128 * gib) == 1
    assert derivation_lanes(4, "optix", 81, cores=4, memory=gib) == 4



def test_derivation_lanes_on_auto_follow_the_machine_and_stay_one_per_worker_where_the_memory_is_unknown(monkeypatch):
    from lfusd.render import overlap, request
    from lfusd.render.overlap import derivation_lanes

    gib = 1 << 30
    for gpu, lanes in ((False, 1), (True, 14)):  # auto renders where Blender finds CUDA/OptiX, else on the CPU
        monkeypatch.setattr(overlap, "nvidia_device", lambda: gpu)
        assert derivation_lanes(1, "auto", 81, cores=16, memory=128 * gib) == lanes

    monkeypatch.setattr(request, "memory_available", lambda: None)
    assert derivation_lanes(2, "cuda", 81, cores=16) == 2
