"""Blender's physical sky: a DomeLight marked ``lfusd:sky = "physical"`` renders as a sky lit from
the stage's sun lamp, as bright on average as the flat dome, and changes no ground truth.

Marked ``render``: five 24x24 views at 4 samples, twice (about 20 s on 2 CPU cores).
"""

from __future__ import annotations

import logging
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pxr import UsdGeom

from lfusd import Dataset
from lfusd.author.labels import set_class_label
from lfusd.author.rigs import add_rig
from lfusd.author.scenes.build import Builder, box, sun_color
from lfusd.author.stage import new_stage
from lfusd.camera import RigSpec
from lfusd.render.job import physical_sky

pytestmark = pytest.mark.render
log = logging.getLogger(__name__)

SUN_AZIMUTH, SUN_ELEVATION = 30.0, 20.0
LOOKS = (30.0, 120.0, 210.0, 300.0)  # rig azimuths; the first faces the sun
DOME, DOME_COLOR = 0.5, (0.55, 0.65, 0.85)
DOWN = 10.0  # degrees the "down" rig looks below the horizon


def _stage(path: Path, physical: bool) -> None:
    stage = new_stage(path)
    b = Builder(stage, path)
    UsdGeom.Xform.Define(stage, "/World/Ground")
    set_class_label(stage.GetPrimAtPath("/World/Ground"), "ground")
    b.mesh("/World/Ground/Slab", box((40.0, 40.0, 0.2), (0.0, 0.0, -0.1)), "concrete")
    b.sun(SUN_AZIMUTH, SUN_ELEVATION, 1.0, color=sun_color(SUN_ELEVATION))
    b.dome(DOME, DOME_COLOR, physical=physical)
    for az in LOOKS:
        a = math.radians(az)
        # 15 degrees up: the lower rows see the ground, the rest the sky around the horizon
        add_rig(stage, RigSpec(name=f"az{int(az):03d}", rows=1, cols=1, width=24, height=24, at=(0.0, 0.0, 1.5),
                               look_at=(math.cos(a), math.sin(a), 1.5 + math.tan(math.radians(15)))))
    # 30 m up, 10 degrees down, away from the sun: the ground's edge (20 m out) lies 56 degrees down,
    # below the view (24.8 degrees either side of its axis): sky above and below the horizon, no ground
    a = math.radians(SUN_AZIMUTH + 180.0)
    add_rig(stage, RigSpec(name="down", rows=1, cols=1, width=24, height=24, at=(0.0, 0.0, 30.0),
                           look_at=(math.cos(a), math.sin(a), 30.0 - math.tan(math.radians(DOWN)))))
    stage.Save()


def _render(stage: Path, out: Path) -> dict[float, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    proc = subprocess.run([sys.executable, "-m", "lfusd", "render", str(stage), "-o", str(out), "--rig", "all",
                           "--samples", "4", "--quiet", "--keys", "rgb_linear,depth,instance"],
                          capture_output=True, text=True, timeout=600, cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 0, proc.stderr[-3000:]
    got = {}
    for az in LOOKS + ("down",):
        d = Dataset(out, rig=az if az == "down" else f"az{int(az):03d}")
        got[az] = tuple(d.read(1, (0, 0), k) for k in ("rgb_linear", "depth", "instance"))
    return got


def _inner(mask: np.ndarray) -> np.ndarray:
    """Pixels of ``mask`` whose 8 neighbours are in it too (the image's pixel filter blends edges)."""
    p = np.pad(mask, 1, constant_values=True)
    h, w = mask.shape
    return np.all([p[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], axis=0)


def test_physical_sky_glows_around_the_sun_is_blue_overhead_and_leaves_ground_truth_alone(tmp_path):
    _stage(tmp_path / "physical.usda", True)
    _stage(tmp_path / "flat.usda", False)
    from pxr import Usd

    assert physical_sky(Usd.Stage.Open(str(tmp_path / "physical.usda")))
    assert not physical_sky(Usd.Stage.Open(str(tmp_path / "flat.usda")))
    phys = _render(tmp_path / "physical.usda", tmp_path / "p")
    flat = _render(tmp_path / "flat.usda", tmp_path / "f")
    down, flat_down = phys.pop("down"), flat.pop("down")
    sky = {az: _inner(np.isinf(depth)) for az, (_, depth, _) in phys.items()}
    assert all(s.mean() > 0.3 and (~s).any() for s in sky.values())  # both sky and ground in every view

    # Ground truth: the same depth and instances whatever the sky (the data render has no world).
    for az in LOOKS:
        assert np.array_equal(phys[az][1], flat[az][1]) and np.array_equal(phys[az][2], flat[az][2])

    # The flat dome is one colour (dome colour x intensity, what Cycles' background shows)...
    for az, (rgb, _, _) in flat.items():
        assert np.allclose(rgb[sky[az]], np.array(DOME_COLOR) * DOME, rtol=1e-2)
    # ...the physical one is brightest towards the sun lamp, a quarter turn off it is darker, and
    # it is as bright as the dome within a factor of 2 on average.
    mean = {az: float(rgb[sky[az]].mean()) for az, (rgb, _, _) in phys.items()}
    assert max(mean, key=mean.get) == SUN_AZIMUTH, mean
    assert mean[SUN_AZIMUTH] > 1.5 * mean[SUN_AZIMUTH + 180.0], mean
    assert 0.5 < np.mean(list(mean.values())) / (DOME * np.mean(DOME_COLOR)) < 2.0, mean
    # Away from the sun the sky is blue (Rayleigh), and bluer higher up.
    rgb, _, _ = phys[SUN_AZIMUTH + 180.0]
    top, low = rgb[0][sky[SUN_AZIMUTH + 180.0][0]], rgb[sky[SUN_AZIMUTH + 180.0]]
    assert (top[:, 2] > 1.2 * top[:, 0]).all()
    assert (top[:, 2] / top[:, 0]).mean() > (low[:, 2] / low[:, 0]).mean()

    # Below the horizon the physical sky is not black (it shows the horizon's haze, darker lower
    # down), so a stage's ground may end before the horizon: the "down" view sees only sky, the
    # rows above the horizon and the rows below it (elevation of each row's centre, column 11.5).
    rgb, depth, instance = down
    assert np.isinf(depth).all() and np.array_equal(depth, flat_down[1]) and np.array_equal(instance, flat_down[2])
    f_px = 39.0 / 36.0 * 24
    elevation = -DOWN + np.degrees(np.arctan((11.5 - np.arange(24)) / f_px))
    lum = rgb.mean(axis=2)
    above, below = lum[(elevation > 1.0) & (elevation < 8.0)], lum[elevation < -1.0]
    assert above.size and below.size
    log.info("physical sky: above the horizon %.3f, below %.3f-%.3f", above.mean(), below.min(), below.max())
    assert below.min() > 0.3 * above.mean()  # not black: at least GROUND_SHADE (0.5) of the horizon, less noise
    assert below.mean() < above.mean()  # darker than the sky above the horizon
    bottom, top = lum[elevation < -20.0].mean(), lum[(elevation < -1.0) & (elevation > -5.0)].mean()
    assert bottom < top  # and darker lower down
