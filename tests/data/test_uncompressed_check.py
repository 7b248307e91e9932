"""The commit's check of uncompressed raw passes (lfusd.data.passes.uncompressed_channels): complete
files pass with their channels and size, as decoding them gives; cut-off or short ones are refused
(OpenEXR 3.5's decoder only prints a warning for a cut-off uncompressed file and returns its
arrays: measured); compressed ones are left to decoding."""

from __future__ import annotations

import numpy as np
import OpenEXR
import pytest

from lfusd.data.passes import _uncompressed_parts, read_exr, read_uncompressed, uncompressed_channels
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


def _blender_like(path, compression, h=6, w=9, single=False):
    """A file as Blender writes its data passes: a Combined RGBA part, one part per pass (a half and
    a uint channel among them), and a colour AOV whose R, G, B, A OpenEXR groups; ``single``: every
    channel in one part (Blender's interleaved multilayer EXR, as the render worker writes it)."""
    rng = np.random.default_rng(11)
    head = {"compression": compression, "type": OpenEXR.scanlineimage}
    f32 = lambda: rng.normal(size=(h, w)).astype(np.float32)  # noqa: E731
    parts = [
        OpenEXR.Part({**head, "name": "ViewLayer.Combined"}, {f"ViewLayer.Combined.{c}": f32() for c in "RGBA"}),
        OpenEXR.Part({**head, "name": "ViewLayer.Depth"}, {"ViewLayer.Depth.Z": f32()}),
        OpenEXR.Part({**head, "name": "ViewLayer.Normal"}, {f"ViewLayer.Normal.{c}": f32() for c in "XYZ"}),
        OpenEXR.Part({**head, "name": "ViewLayer.Extra"}, {"ViewLayer.Extra.H": f32().astype(np.float16),
                                                            "ViewLayer.Extra.U": rng.integers(0, 2**32, (h, w), dtype=np.uint32)}),
        OpenEXR.Part({**head, "name": "ViewLayer.next_position"}, {f"ViewLayer.next_position.{c}": f32() for c in "RGBA"}),
    ]
    if single:
        OpenEXR.File(head, {name: ch.pixels for part in parts for name, ch in part.channels.items()}).write(str(path))
    else:
        OpenEXR.File(parts).write(str(path))


@pytest.mark.parametrize("single", [True, False], ids=["one part", "a part per pass"])
def test_reading_uncompressed_lines_gives_what_decoding_gives(tmp_path, single):
    """read_uncompressed returns the channels read_exr decodes, bit for bit, grouped alike; with
    ``layers`` it leaves out the parts of other passes (Blender's Combined, in a file of a part per pass)."""
    p = tmp_path / "passes.exr"
    _blender_like(p, OpenEXR.NO_COMPRESSION, single=single)
    decoded, read = read_exr(p), read_uncompressed(p)
    assert set(read) == set(decoded) and "ViewLayer.next_position" in read
    for name, a in decoded.items():
        assert read[name].shape == a.shape and read[name].dtype == a.dtype, name
        assert read[name].tobytes() == a.tobytes(), name
    some = read_uncompressed(p, {"Depth", "next_position"})
    assert set(some) == (set(decoded) if single else {"ViewLayer.Depth.Z", "ViewLayer.next_position"})
    assert not some["ViewLayer.Depth.Z"].flags.writeable  # views of one read, not to be written into


def test_reading_refuses_a_cut_off_file_and_leaves_compressed_ones_to_decoding(tmp_path):
    p = tmp_path / "passes.exr"
    _blender_like(p, OpenEXR.NO_COMPRESSION)
    data = p.read_bytes()
    for cut in (1, 40):
        p.write_bytes(data[:-cut])
        with pytest.raises(LfusdError, match="re-render"):
            read_uncompressed(p)
    # a line whose chunk header names another line (a damaged file of the right size): decoding decides
    p.write_bytes(data)
    first = int(_uncompressed_parts(p)[1].offsets[0])  # the Depth part's first line: part number, y, bytes
    damaged = bytearray(data)
    damaged[first + 4] ^= 1
    p.write_bytes(bytes(damaged))
    assert read_uncompressed(p) is None
    _blender_like(p, OpenEXR.ZIP_COMPRESSION)
    assert read_uncompressed(p) is None
