"""The commit's check of uncompressed raw passes (lfusd.data.passes.uncompressed_channels): complete
files pass with their channels and size, as decoding them gives; cut-off or short ones are refused
(OpenEXR 3.5's decoder only prints a warning for a cut-off uncompressed file and returns its
arrays: measured); compressed ones are left to decoding."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest

from lfusd.data.passes import read_exr, uncompressed_channels
from lfusd.errors import LfusdError


def _write(path, compression, h=5, w=7):
    ch = {"ViewLayer.Depth.Z": np.full((h, w), 3.0, np.float32), "ViewLayer.Object Index.X": np.ones((h, w), np.float32),
          "ViewLayer.Normal.X": np.zeros((h, w), np.float16), "ViewLayer.next_position": np.zeros((h, w, 4), np.float32)}
    OpenEXR.File({"compression": compression, "type": OpenEXR.scanlineimage}, ch).write(str(path))


def test_a_complete_uncompressed_file_gives_its_channels_and_size(tmp_path):
    p = tmp_path / "passes.exr"
    _write(p, OpenEXR.NO_COMPRESSION)
    names, shape = uncompressed_channels(p)
    decoded = read_exr(p)
    assert shape == (5, 7) == {a.shape[:2] for a in decoded.values()}.pop()
    assert set(names) == {"ViewLayer.Depth.Z", "ViewLayer.Object Index.X", "ViewLayer.Normal.X",
                          *(f"ViewLayer.next_position.{c}" for c in "RGBA")}


@pytest.mark.parametrize("cut", [1, 8, 100])
def test_a_cut_off_uncompressed_file_is_refused(tmp_path, cut):
    p = tmp_path / "passes.exr"
    _write(p, OpenEXR.NO_COMPRESSION)
    data = p.read_bytes()
    p.write_bytes(data[:-cut])
    with pytest.raises(LfusdError, match="re-render"):
        uncompressed_channels(p)


def test_a_longer_file_is_refused_and_other_files_are_left_to_decoding(tmp_path):
    p = tmp_path / "passes.exr"
    _write(p, OpenEXR.NO_COMPRESSION)
    p.write_bytes(p.read_bytes() + b"\0" * 16)
    with pytest.raises(LfusdError):
        uncompressed_channels(p)
    _write(p, OpenEXR.ZIP_COMPRESSION)
    assert uncompressed_channels(p) is None
    p.write_bytes(b"")
    assert uncompressed_channels(p) is None
    p.write_bytes(b"not an exr at all")
    assert uncompressed_channels(p) is None


def test_a_multi_part_file_as_blender_writes_it(tmp_path):
    """Blender's multilayer EXRs are multi-part files (one part per pass group): every part's lines count."""
    p = tmp_path / "passes.exr"
    head = {"compression": OpenEXR.NO_COMPRESSION, "type": OpenEXR.scanlineimage}
    parts = [OpenEXR.Part({**head, "name": "one"}, {"a.Z": np.ones((5, 7), np.float32)}),
             OpenEXR.Part({**head, "name": "two"}, {"b.X": np.ones((5, 7), np.float16), "b.Y": np.ones((5, 7), np.float32)})]
    OpenEXR.File(parts).write(str(p))
    assert uncompressed_channels(p) == (["a.Z", "b.X", "b.Y"], (5, 7))
    p.write_bytes(p.read_bytes()[:-1])
    with pytest.raises(LfusdError, match="re-render"):
        uncompressed_channels(p)
