"""Stages shaped like assets from other tools, and the pipeline run every such test makes.

Each test of the real-world corpus authors its own stage (Y-up, centimetres, instances, usdz,
...), then calls :func:`render_and_verify`: `lfusd render-video` and `lfusd verify` through the
CLI, with thresholds unchanged, asserting that verification compared pixels for every key it
checked. The test then checks one closed-form quantity of its own against the dataset.
"""

from __future__ import annotations

from pathlib import Path

from lfusd import Dataset
from lfusd.cli import main

# Keys verification must compare on a moving stage, and on any stage (one frame: static keys).
MOTION_KEYS = ("depth", "instance", "flow_fwd", "flow_bwd", "scene_flow", "disparity_change", "occlusion_fwd", "occlusion_bwd")
STATIC_KEYS = ("depth", "instance")


def render_and_verify(stage: Path, out: Path, *extra: str, keys=MOTION_KEYS, rig: str | None = None) -> tuple[Dataset, dict]:
    """Render ``stage`` with `lfusd render-video` (tiny, 1 sample, CPU) and verify it.

    ``extra``: further render-video arguments (``--frames``, ``--light``, ...). Returns the
    dataset and verification's {rig: report}; fails the test unless every one of ``keys`` compared
    more than 0 pixels and every check passed."""
    from lfusd.truth.verify import verify

    argv = ["render-video", str(stage), "-o", str(out), "--samples", "1", "--device", "cpu", "--quiet", *extra]
    if rig:
        argv += ["--rig", rig]
    assert main(argv) == 0, f"render-video failed on {stage}"
    reports = verify(out, rig=rig)
    for name, report in reports.items():
        compared = report.compared()
        for key in keys:
            assert compared.get(key, 0) > 0, f"rig {name}: verify compared no pixel of {key} ({compared})"
        assert report.ok, f"rig {name}: " + "; ".join(report.failures()[:5]) + "\n" + report.table()
    return Dataset(out, rig=rig) if rig else Dataset(out), reports
