"""Format version 2's ground-truth files: each key in the encoding its :class:`lfusd.keys.Storage` names.

    gt.exr      depth (FLOAT), normal.X/.Y/.Z (HALF), instance (UINT): the static keys of the raw passes
    motion.exr  flow_fwd.X/.Y, flow_bwd.X/.Y, scene_flow.X/.Y/.Z, disparity_change (FLOAT rounded to
                fixed point), masks (UINT, bit ``Storage.bits`` per mask key)

Single-part scanline OpenEXR, ZIP, or PXR24 where that keeps every bit (:func:`compression_for`:
motion.exr as a rule, whose floats are fixed point). Measured on the default scene at 1024x1024
(benchmarks/bench_storage.py, docs/storage.md): these channels take 4.58 bytes per pixel
with ZIP against 3.87 with ZSTD, 3.67 with HDF5 gzip+shuffle, 7.44 with HTJ2K, 5.06 with ZIPS and
9.33 with PIZ. ZIP costs about 0.9 bytes per pixel more than the best (about 10 % of a whole
view, 8.7 bytes per pixel with its image) and every OpenEXR reader since 1.x reads it: ZSTD needs
OpenEXR 3.4+ (Blender 5.0 cannot read it, measured: "unable to decompress data"), and HDF5
leaves the image format every other file here uses.
The header attribute ``lfusd.keys`` lists the keys a file holds. Rounding is where the low bits
are noise: flow on a static surface is 1e-5 px of float noise rather than 0 until rounded, which
ZIP cannot compress. No pxr, bpy or torch.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import OpenEXR

from .. import cpu_account
from ..errors import LfusdError
from ..keys import KEYS
from .folder import atomic_write

COMPRESSION = OpenEXR.ZIP_COMPRESSION
# PXR24 stores a FLOAT channel in its top 24 bits (HALF and UINT as they are), byte plane by byte
# plane, deflated: where every float's low 8 bits are 0 it loses nothing, and it is smaller and
# faster than ZIP (motion.exr, 1024x1024: 1.73 against 2.69 MB, write 0.100 against 0.144 s,
# read 0.019 against 0.041 s). Fixed-point rounding leaves those bits 0 up to 2^16 steps
# (flow below 256 px, scene flow below 0.5 m); beyond, and for full floats (depth), ZIP.
EXACT_PXR24_MASK = np.uint32(0xFF)
KEYS_ATTR = "lfusd.keys"  # an EXR header attribute, not a USD property (lfusd.author.vocabulary)
MASKS = "masks"  # the uint32 channel holding every mask key, one bit each
_COMPONENTS = "XYZW"


def channel_names(name: str) -> list[str]:
    """The EXR channels of one key: ``depth``, or ``normal.X``, ``normal.Y``, ``normal.Z``."""
    n = KEYS[name].shape[0] if KEYS[name].shape else 0
    return [f"{name}.{c}" for c in _COMPONENTS[:n]] if n else [name]


def quantize(name: str, array: np.ndarray) -> np.ndarray:
    """The values the encoding of ``name`` keeps, as the key's dtype (what a round trip returns)."""
    st = KEYS[name].storage
    a = np.asarray(array)
    if st.encoding == "fixed":
        scale = 2.0**st.bits
        if a.dtype != np.float32:
            return (np.round(a.astype(np.float64) * scale) / scale).astype(np.float32)
        # float32 throughout gives the same numbers (a power-of-two scale is exact, and so is the
        # rounding) in less than half the time (measured at 1024x1024: 6.0 -> 2.6 ms for flow, 8.7 -> 3.9
        # for scene flow); only |a| beyond 2^(127-bits) overflows, and it is kept
        # as it is (a multiple of 2^-bits already)
        s32 = np.float32(scale)
        with np.errstate(over="ignore", invalid="ignore"):
            q = np.round(a * s32)
            q /= s32
        # float32 spacing >= 2^-bits: nothing to round (and no overflow to undo)
        np.copyto(q, a, where=np.abs(a) >= np.float32(2.0 ** (23 - st.bits)))
        return q
    if st.encoding == "half":
        return a.astype(np.float16).astype(np.float32)
    return a.astype(KEYS[name].dtype)


def encode(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """EXR channels holding ``arrays`` (key -> array in the conventions), each in its encoding."""
    channels: dict[str, np.ndarray] = {}
    masks = None
    for name, a in arrays.items():
        st = KEYS[name].storage
        a = np.asarray(a)
        if st.encoding == "mask":
            bit = a.astype(bool).astype(np.uint32) << np.uint32(st.bits)
            masks = bit if masks is None else masks | bit
            continue
        if st.encoding == "uint32":
            if a.size and a.min() < 0:
                raise LfusdError(f"{name} holds negative ids; it cannot be stored as uint32 (a bug: report it)")
            values = a.astype(np.uint32)
        elif st.encoding == "half":
            values = a.astype(np.float16)
        elif st.encoding in ("float32", "fixed"):
            values = quantize(name, a)
        else:
            raise ValueError(f"{name} ({st.encoding}) is not stored in a ground-truth file")
        comps = channel_names(name)
        for i, ch in enumerate(comps):
            channels[ch] = np.ascontiguousarray(values[..., i] if len(comps) > 1 else values)
    if masks is not None:
        channels[MASKS] = np.ascontiguousarray(masks)
    return channels


def decode(channels: dict[str, np.ndarray], names) -> dict[str, np.ndarray]:
    """The keys ``names`` from EXR channels written by :func:`encode`, as Dataset.read returns them."""
    out = {}
    for name in names:
        k = KEYS[name]
        if k.storage.encoding == "mask":
            out[name] = ((channels[MASKS] >> np.uint32(k.storage.bits)) & np.uint32(1)).astype(bool)
            continue
        comps = [channels[c] for c in channel_names(name)]
        a = np.stack(comps, axis=-1) if k.shape else comps[0]
        out[name] = a.astype(k.dtype)
    return out


def write(path: str | Path, arrays: dict[str, np.ndarray]) -> Path:
    """Write ``arrays`` (key -> array) into one EXR under a temporary name, then rename it into place."""
    return _write(Path(path), arrays, encode(arrays))


def compression_for(channels: dict[str, np.ndarray]):
    """The codec of a ground-truth file: PXR24 where it keeps every bit of ``channels`` (no FLOAT
    channel has a low bit below its top 24 set), else ZIP. Both lossless here, and read by every OpenEXR."""
    for a in channels.values():
        if a.dtype == np.float32 and a.size and np.bitwise_or.reduce(a.view(np.uint32), axis=None) & EXACT_PXR24_MASK:
            return COMPRESSION
    return OpenEXR.PXR24_COMPRESSION


def _write(path: Path, arrays: dict[str, np.ndarray], channels: dict[str, np.ndarray]) -> Path:
    header = {"compression": compression_for(channels), "type": OpenEXR.scanlineimage, KEYS_ATTR: ",".join(arrays)}
    # a copy of the channels: File turns the dict's arrays into Channels
    return atomic_write(path, lambda tmp: OpenEXR.File(header, dict(channels)).write(tmp), prefix=f".{path.stem}.", suffix=".exr")


def write_checked(path: str | Path, arrays: dict[str, np.ndarray]) -> tuple[Path, int]:
    """:func:`write`, then read the file back and compare every channel bit for bit with what was
    encoded (the encodings' error bounds are :func:`check`'s, tested on their own); LfusdError
    naming the first channel that differs. Returns the path and the pixels compared (per key, as
    :func:`check` counts them). A quarter of :func:`check`'s time: no decoding, no float64."""
    path = Path(path)
    with cpu_account.phase("encode"):
        channels = encode(arrays)
        _write(path, arrays, channels)
    with cpu_account.phase("read-back"):
        _compare(path, channels)
    first = next(iter(arrays.values()), None)
    return path, len(arrays) * (int(np.asarray(first).shape[0] * np.asarray(first).shape[1]) if first is not None else 0)


def _compare(path: Path, channels: dict[str, np.ndarray]) -> None:
    """Read ``path`` back and compare every channel bit for bit with ``channels``."""
    try:
        back = {name: ch.pixels for name, ch in OpenEXR.File(str(path)).channels().items()}
    except Exception as e:  # OpenEXR raises plain exceptions for unreadable files
        raise LfusdError(f"cannot read back {path} ({e}); free disk space if it is full, then rerun") from None
    for name, want in channels.items():
        got = back.get(name)
        # bytes, not values: NaN and inf must come back as written too (compared as unsigned integers
        # of the pixel's size: no copies, a tenth of comparing tobytes())
        if got is None or got.shape != want.shape or got.dtype != want.dtype or not _same_bits(got, want):
            raise LfusdError(f"{path}: channel {name} did not read back as written; free disk space if it is full, then rerun "
                             "(a persistent failure is a bug: report it)")


def _same_bits(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two arrays of one shape and dtype hold the same bytes."""
    bits = np.dtype(f"u{a.dtype.itemsize}")
    return np.array_equal(np.ascontiguousarray(a).view(bits), np.ascontiguousarray(b).view(bits))


def read(path: str | Path) -> dict[str, np.ndarray]:
    """Every key of a file written by :func:`write`."""
    try:
        f = OpenEXR.File(str(path))
        names = [n for n in str(f.header()[KEYS_ATTR]).split(",") if n]
        channels = {name: ch.pixels for name, ch in f.channels().items()}
        return decode(channels, names)
    except (KeyError, ValueError, RuntimeError, OSError) as e:
        raise LfusdError(f"cannot read {path} ({str(e).splitlines()[0] if str(e) else type(e).__name__}); "
                         "derive it again (rerun the render command, or 'lfusd derive' for motion.exr)") from None
    except Exception as e:  # OpenEXR raises plain exceptions for missing or corrupt files
        raise LfusdError(f"cannot read {path} ({e}); derive it again (rerun the render command)") from None


def excess(name: str, got: np.ndarray, want: np.ndarray) -> float:
    """How far ``got`` (read back) is outside the storage error of ``name`` around ``want`` (0: inside).

    Non-finite values must come back identical; finite ones within ``Storage.error``, plus half an
    ulp of float32 for fixed point (values beyond 2^(24-bits)) and half's relative 2^-11 for half."""
    st = KEYS[name].storage
    got, want = np.asarray(got), np.asarray(want)
    if got.shape != want.shape:
        return np.inf
    if st.encoding in ("mask", "uint32", "float32", "image"):
        same = np.array_equal(got, want, equal_nan=want.dtype.kind == "f")
        return 0.0 if same else np.inf
    g, w = got.astype(np.float64), want.astype(np.float64)
    finite = np.isfinite(w)
    if not np.array_equal(np.isnan(g), np.isnan(w)) or not np.array_equal(g[~finite & ~np.isnan(w)], w[~finite & ~np.isnan(w)]):
        return np.inf
    if st.encoding == "fixed":
        allowed = st.error + np.spacing(np.abs(want[finite]).astype(np.float32)).astype(np.float64) / 2
    else:  # half
        allowed = np.maximum(2.0**-11 * np.abs(w[finite]), 2.0**-25)
    err = np.abs(g[finite] - w[finite]) - allowed
    return float(max(err.max(initial=0.0), 0.0))


def check(path: str | Path, arrays: dict[str, np.ndarray]) -> int:
    """Read ``path`` back and compare every key with ``arrays`` (what was written) within its storage
    error; LfusdError naming the first key outside it. Returns the pixels compared (summed over keys)."""
    back = read(path)
    compared = 0
    for name, want in arrays.items():
        if name not in back:
            raise LfusdError(f"{path} lost key {name!r} on writing; free disk space if it is full, then rerun")
        bad = excess(name, back[name], want)
        if bad > 0:
            raise LfusdError(f"{path}: {name} read back off by {bad:g} beyond its storage error; "
                             "free disk space if it is full, then rerun (a persistent failure is a bug: report it)")
        compared += int(np.asarray(want).shape[0] * np.asarray(want).shape[1])
    return compared
