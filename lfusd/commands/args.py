"""The one argument layer of the `lfusd` CLI: the parser class and the value types every command uses.

The grammars themselves are pure functions in :mod:`lfusd.camera` (``parse_frames``, ``parse_view``,
``parse_point``, ``parse_grid``, ``parse_resolution``), shared with scripts that cannot import the
CLI; this module turns them into argparse types, so a bad value is a one-line usage error naming
the option before any work starts.

- frames: ``N``, ``A-B`` and comma lists ``1-5,8``, negative time codes too (``-5--2``) (:data:`frames`); commands that need one
  contiguous range use :data:`frame_range`, which says so;
- views: ``R,C`` or ``R_C`` (:data:`view`);
- points: ``X,Y,Z`` in metres, negative coordinates included (:data:`point`);
- pairs: ``ROWSxCOLS`` (:data:`grid`), ``WIDTHxHEIGHT`` (:data:`resolution`);
- thresholds: ``KEY=NUMBER`` (:data:`threshold`).
"""

from __future__ import annotations

import argparse
import re

from ..camera import DISTORTION_COEFFS, Distortion, parse_frames, parse_grid, parse_point, parse_resolution, parse_view
from ..errors import LfusdError
from ..layout import MAX_FRAMES

# Values such as -3, -.5, -0.05,0.6,3 are numbers and coordinates, and -5--2, -2-3 frame ranges: never options.
NEGATIVE_VALUE = re.compile(r"^-\d+$|^-\d*\.\d+$|^-\d*\.?\d*,|^-\d+\s*-")


class Parser(argparse.ArgumentParser):
    """argparse with usage errors on one line, like every other lfusd error, and negative values."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # argparse's own hook for telling negative numbers from options (stable since Python 3.2),
        # widened to coordinate lists; set here so that every command and subcommand shares it.
        self._negative_number_matcher = NEGATIVE_VALUE

    def error(self, message: str):
        self.exit(2, f"lfusd: error: {message} (see '{self.prog} --help')\n")


def _argtype(parse, name: str):
    """An argparse type from a parser raising LfusdError; argparse prefixes the option's name."""

    def convert(text: str):
        try:
            return parse(text)
        except LfusdError as e:
            raise argparse.ArgumentTypeError(str(e)) from e

    convert.__name__ = name
    return convert


def _frames(text: str) -> list[int]:
    return parse_frames(text, limit=MAX_FRAMES)


def _frame_range(text: str) -> tuple[int, int]:
    frames = _frames(text)
    first, last = frames[0], frames[-1]
    if len(frames) != last - first + 1:
        raise LfusdError(f"frames {text!r} are not one contiguous range A-B; this command takes consecutive frames (e.g. {first}-{last})")
    return first, last


def _keys(text: str) -> tuple[str, ...]:
    from ..keys import get

    names = tuple(n.strip() for n in text.split(",") if n.strip())
    if not names:
        raise LfusdError(f"--keys {text!r} names no key; give a comma list such as rgb,depth,flow_fwd")
    for n in names:
        get(n)  # one line naming the unknown key and the known ones
    return names


def _threshold(text: str) -> tuple[str, float]:
    key, _, value = text.partition("=")
    try:
        return key, float(value)
    except ValueError:
        raise LfusdError(f"threshold {text!r} is not KEY=NUMBER (e.g. flow_fwd=0.1)") from None


frames = _argtype(_frames, "frames")
frame_range = _argtype(_frame_range, "frame range")
view = _argtype(parse_view, "view")
point = _argtype(lambda text: parse_point(text, "point"), "point")
grid = _argtype(parse_grid, "grid")
resolution = _argtype(parse_resolution, "resolution")
threshold = _argtype(_threshold, "threshold")
_key_list = _argtype(_keys, "keys")


# What --rig means, by what the command reads: a stage (render, rig-study), one rig of a dataset
# (eval, export, preview), or a subset of a dataset's rigs (derive, verify, view).
RIG_HELP = {
    "stage": "rig name, or 'all' (default: the stage's only rig)",
    "dataset": "rig name, for a dataset that holds several rigs (default: its only rig)",
    "every": "rig name (default: every rig of the dataset)",
}


def add_rig_option(p: argparse.ArgumentParser, reads: str) -> None:
    """The one ``--rig`` option; ``reads`` is a key of :data:`RIG_HELP`."""
    p.add_argument("--rig", default=None, metavar="RIG", help=RIG_HELP[reads])


def add_render_options(p: argparse.ArgumentParser, samples_help: str) -> None:
    """The options `lfusd render` and `lfusd render-video` share, and their `RenderRequest` fields
    (see :func:`render_request_fields`)."""
    from ..render.request import DEVICES, LIGHTS

    p.add_argument("-o", "--out", required=True, help="dataset folder (created; rerunning resumes)")
    add_rig_option(p, "stage")
    p.add_argument("--samples", type=int, default=16, help=f"Cycles samples for {samples_help} (default 16)")
    p.add_argument("--workers", type=int, default=1, help="Blender worker processes / Ray task slots (default 1)")
    p.add_argument("--device", default="auto", choices=DEVICES, help="Cycles device (default auto: OptiX, CUDA, else CPU)")
    p.add_argument("--light", default="auto", choices=LIGHTS,
                   help="a stage without lights: auto adds a neutral sky and sun, none keeps it dark (default auto)")
    p.add_argument("--overwrite", action="store_true", help="replace an lfusd dataset rendered with other settings (only lfusd's own files)")
    p.add_argument("--force", action="store_true", help="render even when the estimated size exceeds the free disk space or memory")
    p.add_argument("--quiet", action="store_true", help="log lines instead of a progress bar")
    p.add_argument("--keys", type=_key_list, default=None, metavar="KEY,...",
                   help="ground-truth keys to store, e.g. rgb,depth,flow_fwd (default: every key the command makes)")
    p.add_argument("--keep-raw", action="store_true", help="keep Blender's raw passes (passes.exr) beside the stored keys")


def add_effect_options(p: argparse.ArgumentParser) -> None:
    """The camera effects' options (docs/CONVENTIONS.md, "Camera effects"), all off by default:
    ``--materials`` and the sensor model's (lfusd.data.sensor; ``--iso`` turns it on and adds rgb_noisy)."""
    g = p.add_argument_group("camera effects (off by default; docs/CONVENTIONS.md)")
    g.add_argument("--shutter", type=float, default=0.0, metavar="FRACTION",
                   help="Cycles' motion blur over this fraction of a frame, centred on it (e.g. 0.5), and the key blur (default 0: none)")
    g.add_argument("--fstop", type=float, default=0.0, metavar="N",
                   help="render through a thin lens of this f-number (with --focus), and add the key coc (default 0: a pinhole)")
    g.add_argument("--focus", type=float, default=0.0, metavar="METRES", help="the distance every view focuses at (with --fstop)")
    g.add_argument("--lens", type=lens_model, default=None, metavar="K1,K2,P1,P2,K3",
                   help="render through this Brown-Conrady (OpenCV) lens distortion; image and ground truth in distorted pixels (default: none)")
    g.add_argument("--lens-seed", type=int, default=None, metavar="S",
                   help="draw each view's lens around --lens from this seed (with --lens-spread), as a real array's lenses differ")
    g.add_argument("--lens-spread", type=float, default=0.0, metavar="X",
                   help="each coefficient of a view's lens is --lens's times (1 + X * N(0, 1)) (with --lens-seed; default 0)")
    g.add_argument("--materials", action="store_true",
                   help="add the material masks transmissive, mirror, emissive and depth_behind (the first opaque surface's depth)")
    g.add_argument("--iso", type=float, default=None, help="add rgb_noisy: the image of a sensor at this ISO (e.g. 800; default: none)")
    g.add_argument("--jpeg", type=int, default=0, metavar="QUALITY", help="JPEG-compress rgb_noisy at this quality 1-100 (default 0: none)")
    g.add_argument("--vignetting", type=float, default=0.3, help="mean corner fall-off of rgb_noisy's cameras, 0-0.95 (default 0.3)")
    g.add_argument("--sensor-seed", type=int, default=0, help="seed of the cameras' variation and the noise (default 0)")


def effect_fields(args: argparse.Namespace) -> dict:
    """The `RenderRequest` fields of :func:`add_effect_options`' options."""
    return dict(materials=args.materials, shutter=args.shutter, fstop=args.fstop, focus=args.focus, sensor=sensor_model(args),
                lens=args.lens, lens_seed=args.lens_seed, lens_spread=args.lens_spread)


def lens_model(text: str):
    """'K1,K2,P1,P2,K3' -> lfusd.camera.Distortion (OpenCV's distCoeffs order)."""
    try:
        values = [float(p) for p in str(text).split(",")]
    except ValueError:
        values = []
    if len(values) != len(DISTORTION_COEFFS):
        raise argparse.ArgumentTypeError(f"{text!r} is not K1,K2,P1,P2,K3 (five numbers, OpenCV's order, e.g. -0.2,0.05,0,0,0)")
    try:
        return Distortion(*values)
    except LfusdError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def sensor_model(args: argparse.Namespace):
    """The `RenderRequest.sensor` of :func:`add_sensor_options`' options (None without --iso)."""
    from ..data.sensor import SensorModel

    if args.iso is None:
        if args.jpeg or args.sensor_seed or args.vignetting != 0.3:
            raise LfusdError("--jpeg, --vignetting and --sensor-seed shape rgb_noisy, made only with --iso; add --iso (e.g. --iso 800)")
        return None
    return SensorModel(iso=args.iso, jpeg=args.jpeg, vignetting=args.vignetting, seed=args.sensor_seed).check()


def run_help(parser: argparse.ArgumentParser):
    """The handler of a command group given no action: its help, exit 2."""

    def run_help(args) -> int:
        parser.print_help()
        return 2

    return run_help


def render_request_fields(args: argparse.Namespace) -> dict:
    """The `RenderRequest` fields of the options :func:`add_render_options` added."""
    from pathlib import Path

    return dict(stage=Path(args.stage), out=Path(args.out), rig=args.rig, samples=args.samples, device=args.device,
                workers=args.workers, light=args.light, overwrite=args.overwrite, force=args.force, quiet=args.quiet,
                keys=args.keys, keep_raw=args.keep_raw)
