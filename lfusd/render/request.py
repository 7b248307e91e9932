"""What a render asks for: the request `lfusd render` and `render-video` build, and its checks."""

from __future__ import annotations

import logging
import math
import os
import shutil
from dataclasses import dataclass, replace
from pathlib import Path

from ..camera import Distortion
from ..data.sensor import SensorModel
from ..errors import LfusdError

DEVICES = ("auto", "cpu", "cuda", "optix")
EXECUTORS = ("local", "ray")
LIGHTS = ("auto", "none")  # auto: a stage without lights gets a neutral sky and sun; none: nothing added

log = logging.getLogger(__name__)

# Bytes per pixel of one view and frame, for the up-front size estimate. Disk: the stored dataset
# (format version 2, measured on the default scene at 1024x1024: 6.6 without and 8.7 with the
# motion keys, docs/storage.md; rounded up), and the raw passes (passes.exr) while they are on
# disk: 12 float32 channels uncompressed, 18 with the motion AOVs, about half that with ZIP
# (measured at the reference rig: 33 of 72). Memory: Blender's render result and film buffers of
# one view, about 200 (a lower bound).
DISK_BYTES_PER_PIXEL = {False: 8, True: 10}
RAW_BYTES_PER_PIXEL = {False: 48, True: 72}
MEMORY_BYTES_PER_PIXEL = 200
# Frames of a view whose raw passes may be on disk at once while motion is derived from them
# (lfusd.truth.derive.REACH frames on either side of the one being derived).
RAW_FRAMES_ON_DISK = 5
@dataclass
class RenderRequest:
    """What `lfusd render` / `render-video` asks for."""

    stage: Path
    out: Path
    rig: str | None = None
    frames: list[int] | None = None
    samples: int = 16
    device: str = "auto"
    workers: int = 1
    resolution: tuple[int, int] | None = None
    overwrite: bool = False
    force: bool = False  # render even when the size estimate exceeds the free disk space or memory
    quiet: bool = False
    executor: str = "local"
    ray_address: str | None = None
    frames_per_unit: int = 10
    motion: bool = False  # also render the t+/-1 position AOVs (render-video)
    light: str = "auto"  # one of LIGHTS
    keys: tuple[str, ...] | None = None  # --keys: the ground-truth keys to store (None: every key the render makes)
    keep_raw: bool = False  # --keep-raw: keep Blender's raw passes.exr beside the stored keys
    materials: bool = False  # --materials: the material masks and depth_behind (render-video)
    fstop: float = 0.0  # --fstop: the beauty through a thin lens of this f-number (0: a pinhole)
    focus: float = 0.0  # --focus: the distance in metres every view of every rig focuses at (with --fstop)
    shutter: float = 0.0  # --shutter: Cycles' motion blur over this fraction of a frame, centred on it; 0: none (render-video)
    sensor: SensorModel | None = None  # --iso ...: the noisy image's sensor model (lfusd.data.sensor); None: no rgb_noisy
    lens: Distortion | None = None  # --lens: every view's Brown-Conrady lens distortion (lfusd.camera.Distortion); None: a pinhole
    lens_seed: int | None = None  # --lens-seed: each view's lens drawn around ``lens`` (lfusd.camera.view_distortion)
    lens_spread: float = 0.0  # --lens-spread: the relative spread of those draws

    def check(self) -> None:
        """Raise LfusdError naming the first impossible setting."""
        if self.samples is None or self.samples < 1:
            raise LfusdError(f"--samples must be a positive integer, got {self.samples}")
        if self.workers is None or self.workers < 1:
            raise LfusdError(f"--workers must be a positive integer, got {self.workers}")
        if self.executor not in EXECUTORS:
            raise LfusdError(f"unknown executor {self.executor!r}; use one of {', '.join(EXECUTORS)}")
        if self.device not in DEVICES:
            raise LfusdError(f"unknown device {self.device!r}; use one of {', '.join(DEVICES)}")
        if self.light not in LIGHTS:
            raise LfusdError(f"unknown --light {self.light!r}; use one of {', '.join(LIGHTS)}")
        if self.ray_address and self.executor != "ray":
            raise LfusdError("--ray-address needs --executor ray")
        if self.sensor is not None:
            self.sensor.check()
        if not (isinstance(self.shutter, (int, float)) and 0 <= self.shutter <= 1):
            raise LfusdError(f"--shutter {self.shutter!r} is not a fraction of a frame in 0-1 (e.g. 0.5)")
        for name, value in (("--fstop", self.fstop), ("--focus", self.focus)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise LfusdError(f"{name} {value!r} is not a non-negative number")
        if bool(self.fstop) != bool(self.focus):
            raise LfusdError("--fstop and --focus go together (a lens's f-number and the distance it focuses at, e.g. --fstop 2.8 --focus 3)")
        check_lens(self.lens, self.lens_seed, self.lens_spread)
        if self.distorted and self.device in ("cuda", "optix"):
            raise LfusdError(f"--lens renders through an OSL camera, which lfusd has checked on the CPU only; use --device cpu "
                             f"(or auto, which renders a --lens job on the CPU) instead of --device {self.device}")
        if self.shutter and not self.motion:
            raise LfusdError("--shutter needs the neighbouring frames that only 'lfusd render-video' renders; render a video")
        if self.materials and not self.motion:
            raise LfusdError("--materials needs the frame's triangles that only 'lfusd render-video' writes; render a video")
        self.stored_keys()

    def stored_keys(self) -> tuple[str, ...]:
        """The keys this render writes (``--keys``, validated against lfusd.keys; LfusdError in one line)."""
        from ..keys import check_wanted

        return check_wanted(self.keys, self.motion, self.keep_raw, self.effects())

    def effects(self) -> tuple[str, ...]:
        """The camera effects (lfusd.keys.EFFECTS) this render turns on."""
        on = {"sensor": self.sensor is not None, "materials": self.materials, "blur": bool(self.shutter), "defocus": bool(self.fstop)}
        return tuple(name for name, yes in on.items() if yes)

    @property
    def distorted(self) -> bool:
        """Whether the views render through a lens distortion (--lens)."""
        return self.lens is not None and not self.lens.is_identity

    def capped(self) -> "RenderRequest":
        """This request with at most one local worker per CPU core (more only compete for them)."""
        cores = usable_cores()
        if self.executor == "local" and self.workers and self.workers > cores:
            log.warning("--workers %d is more than this machine's %d CPU cores; using %d", self.workers, cores, cores)
            return replace(self, workers=cores)
        return self


def check_lens(lens: Distortion | None, seed: int | None, spread: float, names=("--lens", "--lens-seed", "--lens-spread")) -> None:
    """Raise LfusdError unless --lens, --lens-seed and --lens-spread (``names``: how the caller spells them) go together."""
    lens_, seed_, spread_ = names
    if not (isinstance(spread, (int, float)) and math.isfinite(spread) and spread >= 0):
        raise LfusdError(f"{spread_} {spread!r} is not a non-negative number (e.g. 0.05)")
    if (seed is not None or spread) and (lens is None or lens.is_identity):
        raise LfusdError(f"{seed_} and {spread_} draw each view's lens around {lens_}; add {lens_} K1,K2,P1,P2,K3")
    if bool(spread) != (seed is not None):
        raise LfusdError(f"{seed_} and {spread_} go together (e.g. {seed_} 1 {spread_} 0.05)")


def _gb(n: float) -> str:
    return f"{n / 1e9:.3g} GB"


def _free_disk(path: Path) -> int | None:
    p = Path(path).absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        return shutil.disk_usage(p).free
    except OSError:
        return None


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask where the system has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def memory_available() -> int | None:
    """The memory this process may use: the machine's, or less where a container's (cgroup) limit is lower."""
    try:
        ram = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        ram = None
    limit = cgroup_memory_limit()
    return limit if ram is None or (limit is not None and limit < ram) else ram


def cgroup_memory_limit(proc: str = "/proc/self/cgroup", root: str = "/sys/fs/cgroup") -> int | None:
    """The lowest memory limit of this process's cgroup and its ancestors (cgroup v2 ``memory.max``,
    v1 ``memory.limit_in_bytes``), or None where none is set or readable. A container's limit is
    what the kernel enforces: an estimate against the machine's memory would be OOM-killed silently."""
    try:
        lines = Path(proc).read_text().splitlines()
    except OSError:
        return None
    limits = []
    for line in lines:
        hierarchy, _, rest = line.partition(":")
        controllers, _, rel = rest.partition(":")
        if hierarchy == "0" and not controllers:  # v2: one unified tree
            base, name = Path(root), "memory.max"
        elif "memory" in controllers.split(","):  # v1: the memory controller's tree
            base, name = Path(root) / "memory", "memory.limit_in_bytes"
        else:
            continue
        d = base / rel.lstrip("/")
        for folder in [d, *d.parents]:
            try:
                text = (folder / name).read_text().strip()
            except OSError:
                text = ""
            if text.isdigit() and int(text) < 1 << 60:  # v1 writes a huge number for "no limit", v2 "max"
                limits.append(int(text))
            if folder == base:
                break
    return min(limits) if limits else None


def size_estimate(rigs: list[tuple[str, int, int, int]], frames: int, motion: bool, workers: int,
                  keep_raw: bool = False) -> tuple[float, float]:
    """(disk bytes, memory bytes) a render of ``rigs`` (name, views, width, height) over
    ``frames`` frames needs: the dataset's files with the raw passes on disk at once (every frame's
    with ``keep_raw``, ZIP), and the render results of ``workers`` views at once."""
    raw_frames = frames if keep_raw else min(frames, RAW_FRAMES_ON_DISK)
    disk = sum(views * w * h for _, views, w, h in rigs) * (
        frames * DISK_BYTES_PER_PIXEL[motion] + raw_frames * RAW_BYTES_PER_PIXEL[motion] / 2)
    memory = max((w * h for _, _, w, h in rigs), default=0) * MEMORY_BYTES_PER_PIXEL * workers
    return disk, memory


def raw_codec(req: RenderRequest, rigs: list[tuple[str, int, int, int]]) -> str:
    """Blender's codec for the raw passes: NONE where they are transient (no ``--keep-raw``) and
    those of the frames on disk at once fit, uncompressed, in a quarter of the free disk; else ZIP.

    NONE halves the CPU time of Blender's write and the parent's decode (measured at 512x512: 1.2 ->
    0.55 s of CPU per 9 views, and 33 -> 21 ms per view)."""
    if req.keep_raw:
        return "ZIP"
    free = _free_disk(req.out)
    need = sum(views * w * h for _, views, w, h in rigs) * RAW_BYTES_PER_PIXEL[req.motion] * RAW_FRAMES_ON_DISK
    return "NONE" if free is not None and need <= free / 4 else "ZIP"


def check_size(req: RenderRequest, rigs: list[tuple[str, int, int, int]], frames: list[int]) -> None:
    """Refuse, before any work, a render whose estimated files exceed the free disk space under
    ``req.out`` or whose views cannot fit in this machine's memory (``--force`` renders anyway)."""
    if req.force:
        return
    disk, memory = size_estimate(rigs, len(frames), req.motion, req.workers if req.executor == "local" else 1, req.keep_raw)
    free, ram = _free_disk(req.out), memory_available()
    what = ", ".join(f"{name} {views} views of {w}x{h}" for name, views, w, h in rigs)
    if ram is not None and memory > ram:
        raise LfusdError(f"rendering {what} needs about {_gb(memory)} of memory (this machine has {_gb(ram)}); "
                         "lower --resolution or --workers, or pass --force to try anyway")
    if free is not None and disk > free:
        raise LfusdError(f"rendering {what} over {len(frames)} frames needs about {_gb(disk)} of disk ({_gb(free)} free under {req.out}); "
                         "free space, lower --resolution or the frames, or pass --force to try anyway")
