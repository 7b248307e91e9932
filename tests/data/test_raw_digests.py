"""Raw passes are recorded by two digests, of their header and of their chunks (lfusd.data.integrity.file_entry):
the chunk digest names the pixels, so a view rendered again with another header but the same pixels
keeps its neighbours' motion current, and any changed byte, header or pixel, is still caught."""

from __future__ import annotations

import struct

import numpy as np
import OpenEXR
import pytest

from lfusd import layout
from lfusd.data import integrity, passes

H, W = 37, 24  # not a multiple of ZIP's 16 or PIZ's 32 lines per chunk


def _channels(seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    ch = {f"ViewLayer.Position.{c}": rng.normal(size=(H, W)).astype(np.float32) for c in "XYZ"}
    ch["ViewLayer.Depth.Z"] = rng.uniform(1, 9, (H, W)).astype(np.float32)
    return ch


def _write(path, ch, compression=OpenEXR.NO_COMPRESSION, **extra) -> None:
    OpenEXR.File({"compression": compression, "type": OpenEXR.scanlineimage, **extra}, dict(ch)).write(str(path))


def _first_chunk(path) -> int:
    """The smallest offset of any chunk, read from the file's offset tables by OpenEXR's layout
    (docs: OpenEXRFileLayout): the bytes before it are headers and tables alone."""
    data = path.read_bytes()
    flags = struct.unpack_from("<i", data, 4)[0]
    multi, pos, counts = bool(flags & 0x1000), 8, []
    while True:
        attrs, pos = passes._exr_header(data, pos)
        if "chunkCount" in attrs:
            counts.append(struct.unpack("<i", attrs["chunkCount"])[0])
        else:
            y0, y1 = struct.unpack_from("<i", attrs["dataWindow"], 4)[0], struct.unpack_from("<i", attrs["dataWindow"], 12)[0]
            counts.append(-(-(y1 - y0 + 1) // {0: 1, 3: 16, 4: 32}[attrs["compression"][0]]))
        if not multi or data[pos] == 0:
            pos += multi
            break
    offsets = np.frombuffer(data, "<u8", sum(counts), pos)
    assert pos + 8 * sum(counts) <= offsets.min()  # the tables end before the first chunk
    return int(offsets.min())


@pytest.mark.parametrize("compression", [OpenEXR.NO_COMPRESSION, OpenEXR.ZIP_COMPRESSION, OpenEXR.PIZ_COMPRESSION])
def test_the_chunks_start_where_the_offset_tables_put_the_first_one(tmp_path, compression):
    p = tmp_path / layout.PASSES_EXR
    _write(p, _channels(), compression)
    assert passes.chunks_start(p) == _first_chunk(p)
    parts = [OpenEXR.Part({"compression": compression, "type": OpenEXR.scanlineimage}, _channels(k), name=f"p{k}") for k in range(3)]
    OpenEXR.File(parts).write(str(p))
    assert passes.chunks_start(p) == _first_chunk(p)


def test_a_file_the_parser_does_not_know_is_hashed_whole(tmp_path):
    for name, data in (("passes.exr", b"raw passes"), ("passes.exr", b"\x76\x2f\x31\x01" + b"\0" * 3)):
        (tmp_path / name).write_bytes(data)
        entry = integrity.file_entry(tmp_path / name)
        assert set(entry) == {"size", "sha256"}


@pytest.mark.parametrize("compression", [OpenEXR.NO_COMPRESSION, OpenEXR.ZIP_COMPRESSION])
def test_the_same_pixels_under_another_header_keep_their_pixels_digest(tmp_path, compression):
    a, b, c = (tmp_path / k for k in "abc")
    for d in (a, b, c):
        d.mkdir()
    ch = _channels()
    _write(a / layout.PASSES_EXR, ch, compression, Date="2026/12/06 03:04:05", RenderTime="00:00.12")
    _write(b / layout.PASSES_EXR, ch, compression, Date="2026/12/07 11:00:00", RenderTime="00:01.5")  # a re-render
    changed = {**ch, "ViewLayer.Depth.Z": ch["ViewLayer.Depth.Z"].copy()}
    changed["ViewLayer.Depth.Z"][H - 1, W - 1] = np.nextafter(changed["ViewLayer.Depth.Z"][H - 1, W - 1], np.float32(10))
    _write(c / layout.PASSES_EXR, changed, compression, Date="2026/12/06 03:04:05", RenderTime="00:00.12")
    ea, eb, ec = (integrity.file_entry(d / layout.PASSES_EXR) for d in (a, b, c))
    assert set(ea) == {"size", "header", "pixels"} and ea["pixels"].startswith(integrity.RAW_DIGEST + ":")
    assert ea["pixels"] == eb["pixels"] and ea["header"] != eb["header"]
    assert ec["pixels"] != ea["pixels"] and ec["header"] == ea["header"]  # one ulp of the last pixel
    for d in (a, b):
        (d / layout.RGB_EXR).write_bytes(b"rgb")
        integrity.record_render(d)
    assert integrity.motion_inputs({"cur": a / layout.PASSES_EXR}) == integrity.motion_inputs({"cur": b / layout.PASSES_EXR})


@pytest.mark.parametrize("where", ["header", "table", "pixels"])
def test_any_changed_byte_of_recorded_raw_passes_is_damage(tmp_path, where):
    p = tmp_path / layout.PASSES_EXR
    _write(p, _channels())
    (tmp_path / layout.RGB_EXR).write_bytes(b"rgb")
    integrity.record_render(tmp_path)
    assert integrity.render_problems(tmp_path) == []
    start = passes.chunks_start(p)
    data = bytearray(p.read_bytes())
    at = {"header": 20, "table": start - 3, "pixels": len(data) - 5}[where]
    data[at] ^= 0x01
    p.write_bytes(bytes(data))
    assert integrity.render_problems(tmp_path) == [f"{layout.PASSES_EXR} differs from its recorded checksum"]


def test_records_made_with_the_files_sha256_are_checked_as_before(tmp_path):
    """A record from before the split digests (the file's sha256 and a digest of the decoded pixels)."""
    p = tmp_path / layout.PASSES_EXR
    _write(p, _channels())
    (tmp_path / layout.RGB_EXR).write_bytes(b"rgb")
    old = {"size": p.stat().st_size, "sha256": integrity.file_entry(p, split=False)["sha256"], "pixels": "p" * 64}
    integrity.write_record(tmp_path, {"version": 2, "files": {layout.RGB_EXR: integrity.file_entry(tmp_path / layout.RGB_EXR),
                                                              layout.PASSES_EXR: old}})
    assert integrity.render_problems(tmp_path) == []
    assert integrity.motion_inputs({"cur": p})["cur"] == "p" * 64
    data = p.read_bytes()
    p.write_bytes(data[:-1] + bytes([data[-1] ^ 0x01]))
    assert integrity.render_problems(tmp_path) == [f"{layout.PASSES_EXR} differs from its recorded checksum"]


def test_without_mmap_the_digests_and_the_passes_are_the_same(tmp_path, monkeypatch):
    """A file system that cannot map files (some network and FUSE mounts): the digests are read in
    pieces and the raw passes decoded by OpenEXR, with the same results."""
    import mmap

    p = tmp_path / layout.PASSES_EXR
    _write(p, _channels())
    mapped, arrays = integrity.file_entry(p, split=True), passes.read_uncompressed(p)
    integrity._DIGESTS.clear()

    def refuse(*a, **k):
        raise OSError("mmap not supported")

    monkeypatch.setattr(mmap, "mmap", refuse)
    assert integrity.file_entry(p, split=True) == mapped
    assert passes.read_uncompressed(p) is None
    decoded = passes.read_exr(p)
    for name, a in arrays.items():
        assert decoded[name].tobytes() == a.tobytes(), name
