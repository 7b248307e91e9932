"""Research file formats: writers and spec-based readers.

- PFM (Netpbm float map as used by HCI / Middlebury / SceneFlow): ``PF`` (3 channels) or ``Pf``
  (1 channel), ``W H``, a scale whose sign gives the byte order (negative = little-endian), then
  float32 rows from the BOTTOM row up.
- Middlebury .flo: the float32 202021.25 (bytes ``PIEH``), int32 width, int32 height, then
  float32 (u, v) interleaved row by row from the top, all little-endian.
- KITTI 2015 16-bit PNGs: flow is RGB uint16 with R = u*64 + 2^15, G = v*64 + 2^15, B = valid
  (1/0); disparity is one uint16 channel d*256 with 0 = invalid.
- HCI 4D light-field benchmark ``parameters.cfg`` (sections intrinsics / extrinsics / meta).
- HDF5 ``LF`` arrays [U, V, H, W, 3] as BasicLFSR / DistgASR read them (stored in MATLAB's axis
  order [3, W, H, V, U]), optionally as a MATLAB v7.3 .mat.
- Spring .flo5 / .dsp5: HDF5 files holding dataset ``flow`` (H,W,2) or ``disparity`` (H,W), NaN
  where unknown (Spring's flow_IO.py).

PNG I/O goes through OpenCV (which orders colour channels B, G, R in memory).
"""

from __future__ import annotations

import configparser
import io
import os
import re
import shutil
import time
from pathlib import Path

import numpy as np

from ..errors import LfusdError

FLO_MAGIC = 202021.25
FLO_UNKNOWN_THRESH = 1e9  # Middlebury flowIO: a component with |value| > 1e9 marks unknown flow
KITTI_FLOW_SCALE = 64.0
KITTI_DISP_SCALE = 256.0


def _cv2():
    import cv2  # OpenCV: PNG codec with 16-bit support

    return cv2


def link_or_copy(src, dst) -> None:
    """Make ``dst`` a hard link to ``src`` (one file's data shared by the views of a chunk), or a copy
    where the file system has no hard links; an existing ``dst`` is replaced."""
    Path(dst).unlink(missing_ok=True)
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def why_unwritable(path, size: int = 0) -> str:
    """Why a file at ``path`` (of about ``size`` bytes) could not be written, and the fix."""
    folder = Path(path).parent
    if not folder.is_dir():
        return f"its folder {folder} does not exist; create it"
    if not os.access(folder, os.W_OK):
        return f"its folder {folder} is not writable; fix its permissions or choose another destination"
    try:
        if shutil.disk_usage(folder).free <= size + (1 << 20):
            return f"the disk holding {folder} is full; free space"
    except OSError:
        pass
    return "check the destination's disk and permissions"


def _imwrite(path, image: np.ndarray) -> None:
    if not _cv2().imwrite(str(path), image):  # OpenCV says only that it failed: find out why
        raise LfusdError(f"could not write {path}: {why_unwritable(path, image.nbytes)}")


def _need(path: Path) -> Path:
    path = Path(path)
    if not path.is_file():
        raise LfusdError(f"{path} does not exist; check the path")
    return path


# ---- PFM ---------------------------------------------------------------------------------------


def write_pfm(path, array) -> None:
    """Write (H,W) or (H,W,3) floats as a little-endian PFM (rows stored bottom-up)."""
    a = np.asarray(array, dtype=np.float32)
    if a.ndim == 3 and a.shape[2] == 1:
        a = a[..., 0]
    if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 3)):
        raise LfusdError(f"PFM holds (H,W) or (H,W,3) arrays, got {a.shape}")
    header = f"{'PF' if a.ndim == 3 else 'Pf'}\n{a.shape[1]} {a.shape[0]}\n-1.0\n".encode("ascii")
    with open(path, "wb") as f:
        f.write(header)
        f.write(np.ascontiguousarray(a[::-1]).astype("<f4").tobytes())


def read_pfm(path) -> np.ndarray:
    """Read a PFM (either byte order) into a top-down float32 array (H,W) or (H,W,3)."""
    data = _need(path).read_bytes()
    m = re.match(rb"(P[Ff])\s+(\d+)\s+(\d+)\s+([-+0-9.eE]+)\s", data)
    if not m:
        raise LfusdError(f"{path} is not a PFM file (no 'PF'/'Pf' header); give a .pfm written by a PFM writer")
    channels = 3 if m.group(1) == b"PF" else 1
    w, h, scale = int(m.group(2)), int(m.group(3)), float(m.group(4))
    dtype = "<f4" if scale < 0 else ">f4"
    n = w * h * channels
    body = data[m.end() : m.end() + 4 * n]
    if len(body) != 4 * n:
        raise LfusdError(f"{path} is truncated: {len(body)} of {4 * n} data bytes; rewrite the file")
    a = np.frombuffer(body, dtype=dtype).astype(np.float32)
    a = a.reshape((h, w, 3) if channels == 3 else (h, w))
    return np.ascontiguousarray(a[::-1])


# ---- Middlebury .flo ---------------------------------------------------------------------------


def write_flo(path, flow) -> None:
    """Write an (H,W,2) flow (du, dv) as a Middlebury .flo file."""
    f = np.asarray(flow, dtype=np.float32)
    if f.ndim != 3 or f.shape[2] != 2:
        raise LfusdError(f".flo holds (H,W,2) flow, got {f.shape}")
    with open(path, "wb") as fh:
        fh.write(np.array([FLO_MAGIC], "<f4").tobytes())
        fh.write(np.array([f.shape[1], f.shape[0]], "<i4").tobytes())
        fh.write(np.ascontiguousarray(f).astype("<f4").tobytes())


def read_flo(path, unknown_as_nan: bool = False) -> np.ndarray:
    """Read a Middlebury .flo file into (H,W,2) float32; with ``unknown_as_nan`` the pixels the
    format flags unknown (a component beyond :data:`FLO_UNKNOWN_THRESH`) read as NaN."""
    data = _need(path).read_bytes()
    if len(data) < 12 or np.frombuffer(data[:4], "<f4")[0] != np.float32(FLO_MAGIC):
        raise LfusdError(f"{path} is not a Middlebury .flo file (no PIEH tag); give a .flo file")
    w, h = (int(v) for v in np.frombuffer(data[4:12], "<i4"))
    body = data[12 : 12 + 8 * w * h]
    if len(body) != 8 * w * h:
        raise LfusdError(f"{path} is truncated; rewrite the file")
    flow = np.frombuffer(body, "<f4").reshape(h, w, 2).astype(np.float32)
    if unknown_as_nan:
        flow[np.any(np.abs(flow) > FLO_UNKNOWN_THRESH, axis=-1)] = np.nan
    return flow


# ---- KITTI 16-bit PNGs -------------------------------------------------------------------------


def write_kitti_flow(path, flow, valid=None) -> None:
    """Write (H,W,2) flow as a KITTI 16-bit PNG; invalid or non-finite pixels store zeros.

    Precision is 1/64 px; |flow| is clipped below 512 px (the format's range).
    """
    f = np.asarray(flow, dtype=np.float64)
    if f.ndim != 3 or f.shape[2] != 2:
        raise LfusdError(f"KITTI flow holds (H,W,2) flow, got {f.shape}")
    ok = np.all(np.isfinite(f), axis=-1)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    enc = np.clip(np.round(np.nan_to_num(f) * KITTI_FLOW_SCALE + 2**15), 0, 2**16 - 1).astype(np.uint16)
    out = np.zeros(f.shape[:2] + (3,), np.uint16)
    out[..., 2], out[..., 1], out[..., 0] = enc[..., 0], enc[..., 1], ok  # BGR in memory: R = u, G = v, B = valid
    out[~ok] = 0
    _imwrite(path, out)


def read_kitti_flow(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a KITTI flow PNG: ((H,W,2) float32 flow, (H,W) bool valid)."""
    cv2 = _cv2()
    a = cv2.imread(str(_need(path)), cv2.IMREAD_UNCHANGED)
    if a is None or a.dtype != np.uint16 or a.ndim != 3 or a.shape[2] != 3:
        raise LfusdError(f"{path} is not a 16-bit RGB KITTI flow PNG")
    flow = np.stack([a[..., 2], a[..., 1]], axis=-1).astype(np.float32)
    flow = (flow - 2**15) / KITTI_FLOW_SCALE
    valid = a[..., 0] > 0
    flow[~valid] = 0
    return flow, valid


def write_kitti_disparity(path, disparity, valid=None) -> None:
    """Write (H,W) disparity as a KITTI 16-bit PNG (d*256, 0 = invalid; precision 1/256 px).

    Disparities below 1/256 or non-finite are stored as invalid; the maximum is 255.996.
    """
    d = np.asarray(disparity, dtype=np.float64)
    if d.ndim != 2:
        raise LfusdError(f"KITTI disparity holds (H,W) arrays, got {d.shape}")
    ok = np.isfinite(d) & (d > 0)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    enc = np.clip(np.round(np.nan_to_num(d, posinf=0.0, neginf=0.0) * KITTI_DISP_SCALE), 1, 2**16 - 1).astype(np.uint16)
    enc[~ok] = 0
    _imwrite(path, enc)


def read_kitti_disparity(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a KITTI disparity PNG: ((H,W) float32 disparity, (H,W) bool valid)."""
    cv2 = _cv2()
    a = cv2.imread(str(_need(path)), cv2.IMREAD_UNCHANGED)
    if a is None or a.dtype != np.uint16 or a.ndim != 2:
        raise LfusdError(f"{path} is not a 16-bit single-channel KITTI disparity PNG")
    return a.astype(np.float32) / KITTI_DISP_SCALE, a > 0


# ---- plain images ------------------------------------------------------------------------------


def write_png(path, rgb) -> None:
    """Write an (H,W,3) RGB or (H,W) grey uint8/uint16 image as PNG."""
    a = np.asarray(rgb)
    if a.dtype not in (np.uint8, np.uint16):
        raise LfusdError(f"PNG images must be uint8 or uint16, got {a.dtype}")
    if a.ndim == 3:
        a = a[..., ::-1]  # RGB -> OpenCV's BGR
    _imwrite(path, np.ascontiguousarray(a))


def encode_png(rgb) -> bytes:
    """The PNG file of an (H,W,3) RGB or (H,W) grey uint8/uint16 image, as bytes (lossless)."""
    a = np.asarray(rgb)
    if a.dtype not in (np.uint8, np.uint16):
        raise LfusdError(f"PNG images must be uint8 or uint16, got {a.dtype}")
    ok, buf = _cv2().imencode(".png", np.ascontiguousarray(a[..., ::-1] if a.ndim == 3 else a))
    if not ok:
        raise LfusdError(f"could not encode a {a.shape} {a.dtype} image as PNG; report it")
    return buf.tobytes()


def decode_png(data: bytes, name: str = "PNG") -> np.ndarray:
    """The (H,W,3) RGB or (H,W) grey image of PNG bytes (as :func:`read_png` reads a file)."""
    cv2 = _cv2()
    a = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if a is None:
        raise LfusdError(f"{name} is not a readable image")
    if a.ndim == 3:
        a = a[..., 2::-1] if a.shape[2] == 4 else a[..., ::-1]  # BGR(A) -> RGB
    return np.ascontiguousarray(a)


def read_png(path) -> np.ndarray:
    """Read a PNG as (H,W,3) RGB or (H,W) grey, keeping its bit depth."""
    cv2 = _cv2()
    a = cv2.imread(str(_need(path)), cv2.IMREAD_UNCHANGED)
    if a is None:
        raise LfusdError(f"{path} is not a readable image")
    if a.ndim == 3:
        a = a[..., 2::-1] if a.shape[2] == 4 else a[..., ::-1]  # BGR(A) -> RGB
    return np.ascontiguousarray(a)


# ---- HCI parameters.cfg ------------------------------------------------------------------------

HCI_KEYS = {
    "intrinsics": ["focal_length_mm", "image_resolution_x_px", "image_resolution_y_px", "sensor_size_mm", "fstop"],
    "extrinsics": [
        "num_cams_x", "num_cams_y", "baseline_mm", "focus_distance_m",
        "center_cam_x_m", "center_cam_y_m", "center_cam_z_m",
        "center_cam_rx_rad", "center_cam_ry_rad", "center_cam_rz_rad", "offset",
    ],
    "meta": [
        "scene", "category", "date", "version", "authors", "contact", "cycles_seed",
        "disp_min", "disp_max", "frustum_disp_min", "frustum_disp_max", "depth_map_scale",
    ],
}


def blender_euler_xyz(cam_to_world_cv) -> tuple[float, float, float]:
    """Blender XYZ Euler angles of a camera whose OpenCV pose is given (HCI's center_cam_r*_rad)."""
    r = np.asarray(cam_to_world_cv, float)[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # Blender cameras: +y up, look -z
    # R = Rz(rz) @ Ry(ry) @ Rx(rx)
    ry = float(np.arcsin(np.clip(-r[2, 0], -1.0, 1.0)))
    if abs(r[2, 0]) < 1 - 1e-9:
        rx = float(np.arctan2(r[2, 1], r[2, 2]))
        rz = float(np.arctan2(r[1, 0], r[0, 0]))
    else:  # gimbal lock: put all of the remaining rotation into rx
        rz = 0.0
        rx = float(np.arctan2(-r[1, 2], r[1, 1]))
    return rx, ry, rz


def write_hci_config(path, params: dict) -> None:
    """Write an HCI ``parameters.cfg``; ``params`` maps every key of HCI_KEYS to a value."""
    parser = configparser.ConfigParser(delimiters="=")
    for section, keys in HCI_KEYS.items():
        parser.add_section(section)
        for k in keys:
            if k not in params:
                raise LfusdError(f"HCI parameters.cfg needs {section}.{k}; pass it to write_hci_config")
            v = params[k]
            if isinstance(v, (list, tuple)):
                v = ", ".join(str(x) for x in v)
            elif isinstance(v, float):
                v = repr(v)
            parser.set(section, k, str(v))
    with open(path, "w") as f:
        parser.write(f)


def read_hci_config(path) -> dict:
    """Parse an HCI ``parameters.cfg`` into typed values (as the benchmark toolkit's read_parameters)."""
    parser = configparser.ConfigParser(delimiters="=")
    parser.read(_need(path))
    ints = {"image_resolution_x_px", "image_resolution_y_px", "num_cams_x", "num_cams_y"}
    strs = {"scene", "category", "date", "version", "contact"}
    out: dict = {}
    for section, keys in HCI_KEYS.items():
        for k in keys:
            if not parser.has_option(section, k):
                if k in ("offset", "cycles_seed"):  # written by HCI's Blender add-on, absent from some files
                    continue
                raise LfusdError(f"{path} lacks {section}.{k}; it is not a complete HCI parameters.cfg")
            raw = parser.get(section, k)
            if k in ints:
                out[k] = int(raw)
            elif k in strs:
                out[k] = raw
            elif k == "authors":
                out[k] = raw.split(", ")
            else:
                out[k] = float(raw)
    return out


# ---- HDF5 LF arrays ----------------------------------------------------------------------------

LF_AXES_ON_DISK = "C,W,H,V,U"  # MATLAB's column-major [U,V,H,W,C] as HDF5 stores it


def write_lf_h5(path, lf, *, matlab: bool = False, attrs: dict | None = None) -> None:
    """Write a light field ``lf`` [U,V,H,W,3] as dataset ``LF``, laid out as BasicLFSR / DistgASR read it.

    Their preparation scripts (``Generate_Data_for_Training.py`` / ``_Test.py``) read every file
    with ``np.array(h5py.File(f)['LF']).transpose((4, 3, 2, 1, 0))`` and their MATLAB versions
    with ``load``: both give [U,V,H,W,3] only when the dataset on disk is [3,W,H,V,U] (MATLAB's
    column-major order), so both the .h5 and the .mat store that. With ``matlab=True`` the file
    is also a MATLAB v7.3 .mat (512-byte MAT header, ``MATLAB_class``). ``attrs`` go on the root
    of a plain .h5 only.
    """
    import h5py

    lf = np.asarray(lf)
    if lf.ndim != 5 or lf.shape[-1] != 3:
        raise LfusdError(f"LF arrays are [U,V,H,W,3], got {lf.shape}")
    classes = {np.uint8: "uint8", np.uint16: "uint16", np.float32: "single", np.float64: "double"}
    if lf.dtype.type not in classes:
        raise LfusdError(f"LF arrays must be uint8, uint16, float32 or float64, got {lf.dtype}")
    on_disk = np.ascontiguousarray(lf.transpose(4, 3, 2, 1, 0))
    # HDF5 writes into memory; the file is then written by Python: a full disk (ENOSPC) inside
    # HDF5's own writes leaves its objects unclosable and the process crashing (measured: SIGSEGV),
    # while here it is an OSError like any other write's.
    buf = io.BytesIO()
    with h5py.File(buf, "w", **({"userblock_size": 512} if matlab else {})) as f:
        d = f.create_dataset("LF", data=on_disk, compression="gzip")
        if matlab:
            d.attrs["MATLAB_class"] = np.bytes_(classes[lf.dtype.type])
        else:
            f.attrs["axes_on_disk"] = LF_AXES_ON_DISK
            for k, v in (attrs or {}).items():
                f.attrs[k] = v
    if matlab:
        text = f"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: {time.strftime('%a %b %d %H:%M:%S %Y')} HDF5 schema 1.00 .".encode()
        header = text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM"
        buf.seek(0)
        buf.write(header.ljust(512, b"\x00"))
    with open(path, "wb") as out:
        out.write(buf.getbuffer())


def read_lf_h5(path) -> np.ndarray:
    """Read dataset ``LF`` as [U,V,H,W,3] from an HDF5 file or MATLAB v7.3 .mat, as BasicLFSR does
    (the stored [3,W,H,V,U] transposed by (4,3,2,1,0))."""
    import h5py

    with h5py.File(_need(path), "r") as f:
        if "LF" not in f:
            raise LfusdError(f"{path} has no dataset 'LF'; give a light-field HDF5/.mat file")
        a = f["LF"][()]
    if a.ndim != 5 or a.shape[0] != 3:
        raise LfusdError(f"{path}: LF is stored as {a.shape}, not [3,W,H,V,U] (MATLAB order); re-export it with `lfusd export lfmat`")
    return np.ascontiguousarray(a.transpose(4, 3, 2, 1, 0))


# ---- Spring .flo5 / .dsp5 ----------------------------------------------------------------------


def _write_h5_array(path, name: str, a: np.ndarray) -> None:
    import h5py

    with h5py.File(path, "w") as f:  # as Spring's flow_IO.writeFlo5File / writeDsp5File
        f.create_dataset(name, data=a, compression="gzip", compression_opts=5)


def _read_h5_array(path, name: str, what: str) -> np.ndarray:
    import h5py

    try:
        f = h5py.File(_need(path), "r")
    except OSError:
        raise LfusdError(f"{path} is not an HDF5 file; give a Spring {what} file") from None
    with f:
        if name not in f:
            raise LfusdError(f"{path} has no dataset {name!r}; it is not a Spring {what} file")
        return f[name][()]


def write_flo5(path, flow) -> None:
    """Write (H',W',2) flow as a Spring .flo5: HDF5 dataset ``flow``, NaN where unknown."""
    f = np.asarray(flow, dtype=np.float32)
    if f.ndim != 3 or f.shape[2] != 2:
        raise LfusdError(f".flo5 holds (H,W,2) flow, got {f.shape}")
    _write_h5_array(path, "flow", f)


def read_flo5(path) -> np.ndarray:
    """Read a Spring .flo5 (dataset ``flow``)."""
    return _read_h5_array(path, "flow", ".flo5 flow")


def write_dsp5(path, disparity) -> None:
    """Write (H',W') disparity as a Spring .dsp5: HDF5 dataset ``disparity``, NaN where unknown."""
    d = np.asarray(disparity, dtype=np.float32)
    if d.ndim != 2:
        raise LfusdError(f".dsp5 holds (H,W) disparity, got {d.shape}")
    _write_h5_array(path, "disparity", d)


def read_dsp5(path) -> np.ndarray:
    """Read a Spring .dsp5 (dataset ``disparity``)."""
    return _read_h5_array(path, "disparity", ".dsp5 disparity")
