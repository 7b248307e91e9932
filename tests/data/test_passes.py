"""The raw-pass contract (lfusd.keys.RAW_PASSES): the reader reads what the worker is told to write."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import OpenEXR

from lfusd import keys
from lfusd.data import passes

WORKER = Path(__file__).resolve().parents[2] / "lfusd" / "render" / "worker.py"


def _exr(path: Path, h: int = 6, w: int = 8, motion: bool = True, materials: bool = True) -> dict[str, np.ndarray]:
    """A passes.exr as Blender's multilayer output names it (view layer 'ViewLayer'), written from
    the contract alone, with a surface on the left half and background (depth 1e10) on the right.
    Returns the values per pass (float32, before the reader's conversions)."""
    rng = np.random.default_rng(3)
    values, ch = {}, {}
    for p in keys.RAW_PASSES:
        if (p.neighbour and not motion) or (p is keys.MATERIAL_AOV and not materials):
            continue
        a = rng.normal(size=(h, w, len(p.channels))).astype(np.float32)
        if p.key == "depth":
            a = np.where(np.arange(w) < w // 2, rng.uniform(1, 5, (h, w)), 1e10)[..., None].astype(np.float32)
        if p.key == "instance":
            a = rng.integers(1, 9, (h, w, 1)).astype(np.float32)
        if p is keys.MATERIAL_AOV:  # every combination of the flags, as the AOV's float
            a = rng.integers(0, 8, (h, w, 1)).astype(np.float32)
        values[p.key] = a
        if p.aov:  # a COLOR AOV: R, G, B, A (the material flags: grey)
            ch.update({f"ViewLayer.{p.layer}.{c}": np.ascontiguousarray(a[..., min(i, a.shape[-1] - 1)]) for i, c in enumerate("RGB")})
            ch[f"ViewLayer.{p.layer}.A"] = np.ones((h, w), np.float32)
        else:
            ch.update({f"ViewLayer.{name}": np.ascontiguousarray(a[..., i]) for i, name in enumerate(p.channel_names)})
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}, ch).write(str(path))
    return values


def test_the_reader_returns_every_pass_of_the_contract_with_its_dtype_and_channels(tmp_path):
    values = _exr(tmp_path / "passes.exr")
    raw = passes.read_raw(tmp_path / "passes.exr")
    assert list(raw) == [p.key for p in keys.RAW_PASSES] + list(keys.MATERIAL_MASKS)
    surface = values["depth"][..., 0] < keys.BACKGROUND_DEPTH
    assert surface.any() and (~surface).any()
    for p in keys.RAW_PASSES:
        a = raw[p.key]
        assert a.dtype == np.dtype(p.dtype), p.key
        assert a.shape == (6, 8) + ((len(p.channels),) if len(p.channels) > 1 else ()), p.key
        want = values[p.key] if len(p.channels) > 1 else values[p.key][..., 0]
        if p.key == "depth":
            np.testing.assert_array_equal(a[surface], want[surface])
            assert np.isinf(a[~surface]).all()  # Blender's background depth becomes inf
        elif p.key == "instance":
            np.testing.assert_array_equal(a[surface], want[surface].astype(np.int32))
            assert (a[~surface] == 0).all()
        elif p.key == "vector":
            np.testing.assert_array_equal(a, want)  # raw, background included
        elif p.key == "material":
            np.testing.assert_array_equal(a[surface], want[surface].astype(np.int32))
            assert (a[~surface] == 0).all()
            for key, bit in keys.MATERIAL_MASKS.items():  # 1 transmissive, 2 mirror, 4 emissive
                assert raw[key].dtype == bool and np.array_equal(raw[key], (a & bit) != 0), key
            assert raw["transmissive"].any() and raw["emissive"].any() and not raw["mirror"][~surface].any()
        else:
            np.testing.assert_array_equal(a[surface], want[surface])
            assert np.isnan(a[~surface]).all()


def test_a_still_render_has_no_motion_aovs_and_they_are_optional(tmp_path):
    _exr(tmp_path / "passes.exr", motion=False, materials=False)
    raw = passes.read_raw(tmp_path / "passes.exr")
    assert set(raw) == {p.key for p in keys.RAW_PASSES if not p.aov}


def test_the_contract_covers_the_raw_keys_and_the_worker_spells_no_pass_of_its_own():
    """Every raw-pass key of the registry comes from one pass of the contract; the worker takes the
    passes it turns on and its AOV names from the contract, so no pass name is written there."""
    assert {k for k in keys.names(keys.RAW)} <= set(keys.RAW_PASS) | set(keys.MATERIAL_MASKS)
    assert {p.key for p in keys.MOTION_AOVS} == {"next_position", "prev_position"}
    strings = {n.value for n in ast.walk(ast.parse(WORKER.read_text())) if isinstance(n, ast.Constant) and isinstance(n.value, str)}
    attrs = {n.attr for n in ast.walk(ast.parse(WORKER.read_text())) if isinstance(n, ast.Attribute)}
    for p in keys.RAW_PASSES:
        if p.switch:  # a render pass: its ViewLayer switch (its name, such as "Vector", is also a shader socket's)
            assert p.switch not in attrs | strings, p
        else:  # an AOV: its name and its mesh attribute
            assert p.layer not in strings and f"lfusd_{p.neighbour}" not in strings, p


def test_uncompressed_raw_passes_read_as_decoding_reads_them(tmp_path, monkeypatch):
    """Transient raw passes are uncompressed (lfusd.render.request.raw_codec) and read as views of
    their lines: the same arrays, bit for bit, C-ordered and writable, as through OpenEXR's decoder."""
    values = _exr(tmp_path / "zip.exr")
    ch = passes.read_exr(tmp_path / "zip.exr")
    ch["ViewLayer.Combined"] = np.ones((6, 8, 4), np.float32)  # Blender writes it; the reader skips it
    OpenEXR.File({"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}, ch).write(str(tmp_path / "passes.exr"))
    assert passes.read_uncompressed(tmp_path / "passes.exr") is not None
    fast = passes.read_raw(tmp_path / "passes.exr")
    monkeypatch.setattr(passes, "read_uncompressed", lambda *a, **k: None)
    decoded = passes.read_raw(tmp_path / "passes.exr")
    assert list(fast) == list(decoded) == [p.key for p in keys.RAW_PASSES] + list(keys.MATERIAL_MASKS)
    for key, a in decoded.items():
        assert fast[key].dtype == a.dtype and fast[key].shape == a.shape and fast[key].tobytes() == a.tobytes(), key
        assert fast[key].flags.c_contiguous and fast[key].flags.writeable, key
    surface = values["depth"][..., 0] < keys.BACKGROUND_DEPTH
    np.testing.assert_array_equal(fast["next_position"][surface], values["next_position"][surface])
