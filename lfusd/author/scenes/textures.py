"""Procedural, deterministic textures written as PNG files (NumPy + zlib, no imaging library).

Every texture is a pure function of its name: the same bytes on every run and machine, so
stages generated anywhere share one ``textures/`` folder. Textures tile seamlessly.
"""

from __future__ import annotations

import functools
import struct
import zlib
from pathlib import Path

import numpy as np

SIZE = 256


def write_png(path: str | Path, rgb: np.ndarray) -> None:
    """Write an (H, W, 3) uint8 array as an 8-bit RGB PNG (fixed zlib level: stable bytes)."""
    Path(path).write_bytes(png_bytes(rgb))


def png_bytes(rgb: np.ndarray) -> bytes:
    """The bytes :func:`write_png` writes for an (H, W, 3) uint8 array."""
    rgb = np.ascontiguousarray(rgb, dtype=np.uint8)
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[i].tobytes() for i in range(h))

    def chunk(tag: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    return png


def _noise(rng: np.random.Generator, size: int, cells: int) -> np.ndarray:
    """Tileable value noise in [0, 1]: a random cells x cells grid, bilinearly interpolated with wrap."""
    grid = rng.random((cells, cells))
    t = np.arange(size) * cells / size
    i0 = np.floor(t).astype(int)
    f = t - i0
    f = f * f * (3 - 2 * f)  # smoothstep: no visible grid creases
    i1 = (i0 + 1) % cells
    a = grid[np.ix_(i0, i0)] * (1 - f)[None, :] + grid[np.ix_(i0, i1)] * f[None, :]
    b = grid[np.ix_(i1, i0)] * (1 - f)[None, :] + grid[np.ix_(i1, i1)] * f[None, :]
    return a * (1 - f)[:, None] + b * f[:, None]


def fbm(rng: np.random.Generator, size: int = SIZE, octaves: int = 5, base: int = 4) -> np.ndarray:
    """Fractal sum of tileable value noise, normalised to [0, 1]."""
    out = np.zeros((size, size))
    amp, total = 1.0, 0.0
    for o in range(octaves):
        out += amp * _noise(rng, size, min(size, base * 2**o))
        total += amp
        amp *= 0.5
    out /= total
    return (out - out.min()) / max(out.max() - out.min(), 1e-9)


def _mix(a, b, t):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a + (b - a) * t[..., None]


def _to8(img: np.ndarray) -> np.ndarray:
    return np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)


def _asphalt(rng):
    n = fbm(rng)
    speck = (rng.random((SIZE, SIZE)) > 0.93) * 0.25
    return _mix((0.16, 0.16, 0.17), (0.33, 0.33, 0.34), np.clip(n * 0.8 + speck, 0, 1))


def _tiles(rng, c1, c2, grout, n_tiles=4, offset_rows=False):
    n = fbm(rng)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    period = SIZE // n_tiles
    shift = ((yy // period) % 2) * (period // 2) if offset_rows else 0
    gx, gy = (xx + shift) % period, yy % period
    tile_id = ((xx + shift) // period) * 7 + (yy // period) * 13
    shade = (np.sin(tile_id * 12.9898) * 43758.5453) % 1.0  # per-tile tint, deterministic
    img = _mix(c1, c2, np.clip(0.5 * shade + 0.5 * n, 0, 1))
    line = (gx < 3) | (gy < 3)
    img[line] = grout
    return img


def _bricks(rng):
    n = fbm(rng)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    bh, bw = SIZE // 16, SIZE // 8
    shift = ((yy // bh) % 2) * (bw // 2)
    gx, gy = (xx + shift) % bw, yy % bh
    bid = ((xx + shift) // bw) * 31 + (yy // bh) * 17
    shade = (np.sin(bid * 78.233) * 43758.5453) % 1.0
    img = _mix((0.45, 0.17, 0.10), (0.70, 0.35, 0.22), np.clip(0.6 * shade + 0.4 * n, 0, 1))
    img[(gx < 2) | (gy < 2)] = (0.72, 0.70, 0.66)
    # windows: a 2 x 2 grid of dark glass panes with frames (the texture spans one storey)
    wx, wy = xx % (SIZE // 2), yy % (SIZE // 2)
    win = (wx > 40) & (wx < 88) & (wy > 30) & (wy < 100)
    frame = (wx > 36) & (wx < 92) & (wy > 26) & (wy < 104) & ~win
    img[frame] = (0.85, 0.85, 0.82)
    img[win] = _mix((0.10, 0.14, 0.20), (0.35, 0.45, 0.55), n)[win]
    return img


def _grass(rng):
    n = fbm(rng, base=8)
    blades = rng.random((SIZE, SIZE))
    return _mix((0.10, 0.28, 0.06), (0.36, 0.55, 0.16), np.clip(0.6 * n + 0.4 * blades, 0, 1))


def _wood(rng):
    n = fbm(rng, base=2)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    rings = 0.5 + 0.5 * np.sin(2 * np.pi * (yy / SIZE * 12 + 2.0 * n))  # 12 periods: tileable
    planks = ((xx % (SIZE // 4)) < 2)
    img = _mix((0.38, 0.22, 0.10), (0.66, 0.45, 0.26), np.clip(0.7 * rings + 0.3 * n, 0, 1))
    img[planks] = (0.20, 0.12, 0.06)
    return img


def _water(rng):
    n = fbm(rng, base=4)
    m = fbm(rng, base=16, octaves=3)
    return _mix((0.05, 0.16, 0.22), (0.20, 0.42, 0.50), np.clip(0.6 * n + 0.4 * m, 0, 1))


def _plaster(rng):
    n = fbm(rng, base=8)
    return _mix((0.70, 0.66, 0.58), (0.90, 0.87, 0.80), n)


def _wallpaper(rng):
    n = fbm(rng, base=8)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    stripes = ((xx // 16) % 2).astype(float)
    dots = (((xx % 32) - 16) ** 2 + ((yy % 32) - 16) ** 2 < 20).astype(float)
    img = _mix((0.60, 0.66, 0.55), (0.75, 0.78, 0.66), np.clip(0.5 * stripes + 0.3 * n, 0, 1))
    img[dots > 0] = (0.45, 0.30, 0.25)
    return img


def _fabric(rng):
    n = fbm(rng, base=16, octaves=3)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    check = (((xx // 32) + (yy // 32)) % 2).astype(float)
    weave = 0.5 + 0.5 * np.sin(xx * np.pi / 2) * np.sin(yy * np.pi / 2)
    return _mix((0.55, 0.12, 0.10), (0.85, 0.75, 0.55), np.clip(0.6 * check + 0.2 * weave + 0.2 * n, 0, 1))


def _paint(color):
    def make(rng):
        n = fbm(rng, base=4, octaves=3)
        c = np.asarray(color, float)
        return _mix(c * 0.75, np.minimum(c * 1.15, 1.0), n)

    return make


def _bark(rng):
    n = fbm(rng, base=4)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    grooves = 0.5 + 0.5 * np.sin(2 * np.pi * (xx / SIZE * 16 + 1.5 * n))
    return _mix((0.18, 0.11, 0.06), (0.42, 0.30, 0.20), grooves)


def _leaves(rng):
    n = fbm(rng, base=16)
    spots = rng.random((SIZE, SIZE))
    return _mix((0.05, 0.20, 0.04), (0.30, 0.50, 0.12), np.clip(0.5 * n + 0.5 * spots, 0, 1))


def _concrete(rng):
    n = fbm(rng, base=8)
    return _mix((0.45, 0.45, 0.43), (0.68, 0.67, 0.64), n)


def _ceramic(rng):
    n = fbm(rng, base=4, octaves=3)
    yy, _ = np.mgrid[0:SIZE, 0:SIZE]
    band = ((yy // 24) % 4 == 0).astype(float)
    img = _mix((0.80, 0.82, 0.86), (0.93, 0.94, 0.96), n)
    img[band > 0] = (0.15, 0.30, 0.60)
    return img


def _dirt(rng):
    n = fbm(rng, base=8)
    pebbles = (rng.random((SIZE, SIZE)) > 0.97).astype(float)
    return _mix((0.30, 0.22, 0.14), (0.52, 0.42, 0.30), np.clip(0.8 * n + 0.5 * pebbles, 0, 1))


def _glass(rng):
    # faint streaks and smudges: something for stereo matching on the pane itself
    n = fbm(rng, base=8, octaves=4)
    yy, _ = np.mgrid[0:SIZE, 0:SIZE]
    streaks = 0.5 + 0.5 * np.sin(2 * np.pi * (yy / SIZE * 6 + 0.8 * n))
    # dark: the pane's own (diffuse) share of the image stays small beside what shows through it
    return _mix((0.16, 0.21, 0.24), (0.34, 0.41, 0.45), np.clip(0.6 * n + 0.4 * streaks, 0, 1))


def _chrome(rng):
    n = fbm(rng, base=4, octaves=3)
    return _mix((0.62, 0.63, 0.65), (0.90, 0.91, 0.93), n)


def _tyre(rng):
    """A wheel: rubber with tread at the texture's border, a silver rim with five spokes in the
    disc centred on (0.5, 0.5) (the wheel's caps map onto it)."""
    n = fbm(rng, base=8, octaves=3)
    yy, xx = (np.mgrid[0:SIZE, 0:SIZE] + 0.5) / SIZE - 0.5
    r = np.hypot(xx, yy) * 2  # 1 at the disc's edge
    a = np.arctan2(yy, xx)
    img = _mix((0.05, 0.05, 0.055), (0.14, 0.14, 0.15), n)
    tread = (np.floor(((xx + 0.5) * 32) % 2) == 0) & (r > 1.0)
    img[tread] *= 0.6
    rim = r < 0.66
    img[rim] = _mix((0.55, 0.56, 0.58), (0.85, 0.86, 0.88), n)[rim]
    hole = rim & (r > 0.2) & (r < 0.56) & (np.cos(5 * a) < 0.3)  # between five spokes
    img[hole] = (0.03, 0.03, 0.035)
    img[(r > 0.62) & (r < 0.66)] = (0.30, 0.30, 0.32)
    return img


def _books(rng):
    """Rows of book spines (one shelf board of books spans the texture's height)."""
    n = fbm(rng, base=8, octaves=3)
    yy, xx = np.mgrid[0:SIZE, 0:SIZE]
    edges = np.cumsum(rng.integers(6, 18, 64))
    spine = np.searchsorted(edges, xx % SIZE, side="right")
    palette = np.array([(0.55, 0.10, 0.08), (0.10, 0.25, 0.50), (0.15, 0.40, 0.20), (0.75, 0.65, 0.35),
                        (0.30, 0.20, 0.15), (0.80, 0.78, 0.72), (0.20, 0.20, 0.22)])
    colour = palette[(spine * 5 + 3) % len(palette)]
    tall = 0.55 + 0.4 * ((spine * 37 % 11) / 10.0)
    up = (SIZE - 1 - yy) / SIZE  # height above the shelf board (row 0 is the top of the image)
    img = colour * (0.8 + 0.3 * n[..., None])
    band = (yy % 40 < 3) & (up < tall)
    img[band] = img[band] * 0.5 + 0.4
    img[up > tall] = (0.12, 0.09, 0.07)  # the shelf's back above shorter books
    img[(xx % SIZE) == 0] = (0.05, 0.05, 0.05)
    return img


TEXTURES = {
    "asphalt": _asphalt,
    "paving": lambda rng: _tiles(rng, (0.55, 0.53, 0.50), (0.72, 0.70, 0.66), (0.35, 0.34, 0.32)),
    "bricks": _bricks,
    "grass": _grass,
    "wood": _wood,
    "water": _water,
    "plaster": _plaster,
    "wallpaper": _wallpaper,
    "fabric": _fabric,
    "bark": _bark,
    "leaves": _leaves,
    "concrete": _concrete,
    "ceramic": _ceramic,
    "dirt": _dirt,
    "floor_tiles": lambda rng: _tiles(rng, (0.50, 0.48, 0.45), (0.66, 0.64, 0.60), (0.26, 0.26, 0.26), 8, True),
    "paint_red": _paint((0.70, 0.08, 0.06)),
    "paint_blue": _paint((0.08, 0.20, 0.62)),
    "paint_white": _paint((0.82, 0.82, 0.80)),
    "paint_yellow": _paint((0.85, 0.65, 0.08)),
    "paint_dark": _paint((0.12, 0.12, 0.13)),
    "paint_green": _paint((0.10, 0.38, 0.18)),
    "paint_silver": _paint((0.62, 0.64, 0.66)),
    "glass": _glass,
    "chrome": _chrome,
    "tyre": _tyre,
    "books": _books,
    "leaves_light": lambda rng: _mix((0.16, 0.34, 0.06), (0.52, 0.66, 0.20), np.clip(0.5 * fbm(rng, base=16) + 0.5 * rng.random((SIZE, SIZE)), 0, 1)),
    "metal": _paint((0.35, 0.37, 0.40)),
    "skin": _paint((0.78, 0.58, 0.45)),
    "hair": lambda rng: _mix((0.06, 0.04, 0.03), (0.25, 0.16, 0.09), fbm(rng, base=32, octaves=2)),
    "denim": lambda rng: _mix((0.10, 0.16, 0.32), (0.30, 0.40, 0.58), np.clip(0.5 * fbm(rng, base=16, octaves=3) + 0.5 * rng.random((SIZE, SIZE)), 0, 1)),
}


# Random patterns for training scenes (the ``things`` template): ``pattern_00`` ... each drawn from
# its own index (not the name's bytes, which the family shares), two or three random colours
# over one of several structures, so that a scene's textures differ in colour, scale and kind.
PATTERNS = 48


def _pattern(index: int):
    def make(_rng):
        rng = np.random.default_rng([0x7A77, index])
        colours = rng.random((3, 3)) ** 1.5  # favour darker and saturated colours, as photographs have
        kind = int(rng.integers(6))
        yy, xx = np.mgrid[0:SIZE, 0:SIZE]
        n = fbm(rng, base=int(rng.choice([2, 4, 8, 16])), octaves=int(rng.integers(2, 6)))
        if kind == 0:  # smooth noise
            t = n
        elif kind == 1:  # stripes, warped
            period = int(rng.choice([8, 16, 32, 64]))
            t = 0.5 + 0.5 * np.sin(2 * np.pi * (xx + 24 * n) / period)
        elif kind == 2:  # checks (edges a quarter period off the wrap: no hard edge at the seam)
            period = int(rng.choice([16, 32, 64]))
            q = period // 4
            t = ((((xx + q) // period) + ((yy + q) // period)) % 2).astype(float) * 0.8 + 0.2 * n
        elif kind == 3:  # dots
            period = int(rng.choice([16, 32, 64]))
            gx, gy = (xx % period) - period / 2, (yy % period) - period / 2
            t = (np.hypot(gx, gy) < period * float(rng.uniform(0.2, 0.45))).astype(float) * 0.85 + 0.15 * n
        elif kind == 4:  # cells of random shades
            cells = int(rng.choice([4, 8, 16]))
            half = SIZE // (2 * cells)  # cell edges half a cell off the wrap, as the checks'
            shade = rng.random((cells, cells))
            t = 0.7 * shade[((yy + half) * cells // SIZE) % cells, ((xx + half) * cells // SIZE) % cells] + 0.3 * n
        else:  # speckle over noise
            t = np.clip(0.6 * n + 0.4 * rng.random((SIZE, SIZE)), 0, 1)
        img = _mix(colours[0], colours[1], t)
        if rng.random() < 0.5:  # a third colour in blotches
            img = img + (colours[2] - img) * (fbm(rng, base=4, octaves=2) > 0.65)[..., None] * 0.8
        return img

    return make


TEXTURES.update({f"pattern_{i:02d}": _pattern(i) for i in range(PATTERNS)})

# Surface detail maps beside each colour texture: ``<name>_normal.png`` (tangent-space normals,
# OpenGL convention: +x along u, +y along v) and ``<name>_roughness.png`` (grey, variation about
# the material's roughness). Both follow the colour's own structure (grout, planks, bark grooves
# are recessed and rougher) plus fine noise. By name: relief (the height field's slope scale: 0
# flat, 1: bricks' grout edges tilt about 30 degrees) and roughness spread (the map spans
# the material's roughness +- half of it).
DETAIL_SUFFIXES = ("normal", "roughness")
RELIEF: dict[str, float] = {
    "bricks": 1.0, "paving": 0.9, "floor_tiles": 0.6, "wood": 0.5, "bark": 1.0, "asphalt": 0.6, "concrete": 0.5,
    "dirt": 0.8, "grass": 0.7, "plaster": 0.4, "tyre": 0.8, "books": 0.4, "leaves": 0.6, "leaves_light": 0.6,
    "fabric": 0.5, "denim": 0.5, "water": 0.35, "skin": 0.12, "hair": 0.6, "wallpaper": 0.2,
}
RELIEF_DEFAULT = 0.15  # paints, metal, glass, chrome, ceramic: a faint orange peel
SPREAD: dict[str, float] = {"glass": 0.1, "water": 0.1, "chrome": 0.3, "ceramic": 0.3}
SPREAD_DEFAULT = 0.6


def _seed(name: str) -> int:
    return int.from_bytes(name.encode("utf-8")[:8].ljust(8, b"\0"), "little")


def texture_pixels(name: str) -> np.ndarray:
    """The (256, 256, 3) uint8 image of texture ``name`` (a colour texture, or ``<colour>_normal``
    and ``<colour>_roughness`` detail maps); seeded by the name's bytes, not hash()."""
    base, _, kind = name.rpartition("_")
    if kind in DETAIL_SUFFIXES and base in TEXTURES:
        return _to8(_detail(base, kind))
    return _to8(TEXTURES[name](np.random.default_rng(_seed(name))))


def _blur(img: np.ndarray) -> np.ndarray:
    """A wrapped 3x3 binomial blur (tileable in, tileable out)."""
    k = (np.roll(img, 1, 0) + 2 * img + np.roll(img, -1, 0)) / 4
    return (np.roll(k, 1, 1) + 2 * k + np.roll(k, -1, 1)) / 4


def _height(base: str) -> np.ndarray:
    """A tileable height field in [0, 1] for colour texture ``base``: its luminance (dark grout,
    gaps and grooves low), softened, plus fine noise."""
    rgb = TEXTURES[base](np.random.default_rng(_seed(base)))
    lum = np.clip(rgb, 0, 1) @ np.array([0.2126, 0.7152, 0.0722])
    fine = fbm(np.random.default_rng(_seed(base) ^ 0x5EED), base=32, octaves=3)
    h = 0.75 * _blur(_blur(lum)) + 0.25 * fine
    return (h - h.min()) / max(h.max() - h.min(), 1e-9)


DETAIL_SIZE = SIZE // 2  # detail maps at half the colour's resolution: a quarter of the bytes


def _detail(base: str, kind: str) -> np.ndarray:
    h = _height(base)
    h = (h[0::2, 0::2] + h[1::2, 0::2] + h[0::2, 1::2] + h[1::2, 1::2]) / 4  # DETAIL_SIZE, still tileable
    if kind == "roughness":  # recesses collect dirt: rougher where low; 0.5 is the material's own
        spread = SPREAD.get(base, SPREAD_DEFAULT)
        r = 0.5 + spread * (0.5 - h)
        return np.repeat(np.clip(r, 0, 1)[..., None], 3, axis=2)
    # the surface z = relief * h * DETAIL_SIZE / 64, in texels
    return normal_map(h * RELIEF.get(base, RELIEF_DEFAULT) * DETAIL_SIZE / 64) * 0.5 + 0.5


def normal_map(height: np.ndarray) -> np.ndarray:
    """Unit tangent-space normals (H, W, 3) of the tileable surface z = ``height`` (in texels; row
    0 is the top of the image, where v is largest): x along u (columns), y along v (up the image)."""
    dh_du = (np.roll(height, -1, 1) - np.roll(height, 1, 1)) / 2
    dh_dv = -(np.roll(height, -1, 0) - np.roll(height, 1, 0)) / 2
    n = np.stack([-dh_du, -dh_dv, np.ones_like(height)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


_VERIFIED: set[str] = set()


def ensure_texture(folder: str | Path, name: str) -> Path:
    """Write ``folder/name.png`` unless it already holds this texture's exact pixels (checked
    once per process; a stale or foreign file of that name is replaced)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.png"
    key = str(path.resolve())
    if key in _VERIFIED and path.exists():
        return path
    pixels, png = _texture(name)
    if not (path.exists() and _same_pixels(path, pixels)):
        tmp = folder / f".{name}.png.tmp"
        tmp.write_bytes(png)
        tmp.replace(path)
    _VERIFIED.add(key)
    return path


@functools.lru_cache(maxsize=None)
def _texture(name: str) -> tuple[np.ndarray, bytes]:
    """Texture ``name``'s pixels and PNG bytes, made once per process: every new stage folder gets
    the same files (drawing and compressing them took about 1.5 s of a dynamic street's generation)."""
    pixels = texture_pixels(name)
    pixels.flags.writeable = False
    return pixels, png_bytes(pixels)


def _same_pixels(path: Path, pixels: np.ndarray) -> bool:
    """Does the PNG at ``path`` (as :func:`write_png` writes them: 8-bit RGB, no filter) hold ``pixels``?"""
    data = path.read_bytes()
    h, w, _ = pixels.shape
    if data[:8] != b"\x89PNG\r\n\x1a\n" or data[16:26] != struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)[:10]:
        return False
    raw, pos = b"", 8
    while pos + 8 <= len(data):
        size, tag = struct.unpack(">I", data[pos:pos + 4])[0], data[pos + 4:pos + 8]
        if tag == b"IDAT":
            raw += data[pos + 8:pos + 8 + size]
        pos += 12 + size
    try:
        rows = np.frombuffer(zlib.decompress(raw), np.uint8).reshape(h, 1 + w * 3)
    except (zlib.error, ValueError):
        return False
    return bool(np.all(rows[:, 0] == 0)) and np.array_equal(rows[:, 1:].reshape(h, w, 3), pixels)
