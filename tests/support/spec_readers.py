"""Readers written from the format specifications with the standard library only, independent of
lfusd.data.formats and of OpenCV: they check the bytes lfusd writes, not lfusd's own readers."""

from __future__ import annotations

import configparser
import struct
import zlib

import numpy as np


def read_png_spec(path) -> np.ndarray:
    """Decode a non-interlaced greyscale or RGB PNG of bit depth 8 or 16 (PNG spec, section 9)."""
    data = open(path, "rb").read()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG"
    pos, idat, ihdr = 8, b"", None
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos : pos + 4])
        ctype = data[pos + 4 : pos + 8]
        body = data[pos + 8 : pos + 8 + length]
        pos += 12 + length
        if ctype == b"IHDR":
            ihdr = struct.unpack(">IIBBBBB", body)
        elif ctype == b"IDAT":
            idat += body
        elif ctype == b"IEND":
            break
    w, h, depth, colour, _, _, interlace = ihdr
    assert interlace == 0 and colour in (0, 2) and depth in (8, 16)
    ch = 3 if colour == 2 else 1
    bpp = ch * depth // 8
    stride = w * bpp
    raw = zlib.decompress(idat)
    out = bytearray()
    prev = bytearray(stride)
    for y in range(h):
        ftype = raw[y * (stride + 1)]
        line = bytearray(raw[y * (stride + 1) + 1 : (y + 1) * (stride + 1)])
        for x in range(stride):
            a = line[x - bpp] if x >= bpp else 0
            b = prev[x]
            c = prev[x - bpp] if x >= bpp else 0
            if ftype == 1:
                line[x] = (line[x] + a) & 255
            elif ftype == 2:
                line[x] = (line[x] + b) & 255
            elif ftype == 3:
                line[x] = (line[x] + (a + b) // 2) & 255
            elif ftype == 4:
                p = a + b - c
                pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
                pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
                line[x] = (line[x] + pred) & 255
        out += line
        prev = line
    arr = np.frombuffer(bytes(out), dtype=">u2" if depth == 16 else np.uint8).astype(np.uint16 if depth == 16 else np.uint8)
    return arr.reshape((h, w, ch) if ch == 3 else (h, w))


def read_pfm_spec(path) -> np.ndarray:
    """PFM: 'Pf'/'PF' line, 'W H' line, scale line (negative = little-endian), rows bottom to top."""
    with open(path, "rb") as f:
        kind = f.readline().strip()
        w, h = (int(x) for x in f.readline().split())
        scale = float(f.readline())
        fmt = "<" if scale < 0 else ">"
        ch = 3 if kind == b"PF" else 1
        vals = struct.unpack(f"{fmt}{w * h * ch}f", f.read(4 * w * h * ch))
    rows = [vals[i * w * ch : (i + 1) * w * ch] for i in range(h)]
    rows.reverse()  # first stored row is the bottom of the image
    a = np.array(rows, dtype=np.float32)
    return a.reshape(h, w, 3) if ch == 3 else a


def read_flo_spec(path) -> np.ndarray:
    """Middlebury .flo: float 202021.25, int32 width, int32 height, (u, v) float32 row-major."""
    with open(path, "rb") as f:
        (tag,) = struct.unpack("<f", f.read(4))
        assert tag == 202021.25
        w, h = struct.unpack("<ii", f.read(8))
        vals = struct.unpack(f"<{w * h * 2}f", f.read(8 * w * h))
    return np.array(vals, np.float32).reshape(h, w, 2)


def read_hci_cfg_spec(path) -> dict:
    """The HCI toolkit's read_parameters: which keys it needs from which section, and their types."""
    p = configparser.ConfigParser()
    p.read(path)
    g = p.get
    return {
        "width": int(g("intrinsics", "image_resolution_x_px")),
        "height": int(g("intrinsics", "image_resolution_y_px")),
        "focal_length_mm": float(g("intrinsics", "focal_length_mm")),
        "sensor_size_mm": float(g("intrinsics", "sensor_size_mm")),
        "fstop": float(g("intrinsics", "fstop")),
        "num_cams_x": int(g("extrinsics", "num_cams_x")),
        "num_cams_y": int(g("extrinsics", "num_cams_y")),
        "baseline_mm": float(g("extrinsics", "baseline_mm")),
        "focus_distance_m": float(g("extrinsics", "focus_distance_m")),
        **{k: float(g("extrinsics", k)) for k in ("center_cam_x_m", "center_cam_y_m", "center_cam_z_m", "center_cam_rx_rad", "center_cam_ry_rad", "center_cam_rz_rad")},
        **{k: float(g("meta", k)) for k in ("disp_min", "disp_max", "frustum_disp_min", "frustum_disp_max", "depth_map_scale")},
        **{k: g("meta", k) for k in ("scene", "category", "date", "version", "contact")},
        "authors": g("meta", "authors").split(", "),
    }
