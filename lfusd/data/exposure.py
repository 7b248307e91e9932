"""Exposure of a dataset's images: a check after rendering, and one automatic exposure per dataset.

lfusd stores the beauty render as rendered, scene-referred linear RGB (``rgb_linear``), and its
8-bit ``rgb`` through the sRGB transfer function at gain 1. A stage lit too weakly (a DistantLight
of intensity 3 renders at about 0.0015 linear) gives black 8-bit images; one lit too strongly
(linear values of 24) gives white ones. Neither is an error of the ground truth, but both make the
images useless, so :func:`exposure_problems` says so after a render, one line per rig.

:func:`auto_gain` is the documented automatic exposure: one gain per dataset (never per view, so
that every view and frame of the light field keeps the same brightness relation), chosen so that
the brightest :data:`BRIGHT_PERCENTILE` % of the sampled pixels reach :data:`BRIGHT_TARGET` of
white; :class:`Exposed` reads a dataset with ``rgb`` made from ``rgb_linear`` times that gain
(``lfusd export --exposure auto``). The sampled pixels are the centre view of at most
:data:`SAMPLED_FRAMES` frames spread over the dataset.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import LfusdError
from .passes import linear_to_srgb8

log = logging.getLogger(__name__)

SAMPLED_FRAMES = 16
BRIGHT_PERCENTILE = 99.0
BRIGHT_TARGET = 0.9  # linear: the bright end just below white, so little clips
DARK_8BIT = 32  # the brightest 1 % of pixels below this (of 255): the images are nearly black
CLIPPED_SHARE = 0.2  # more than this share of pixels at white in every channel: overexposed


def _luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance of linear RGB."""
    return np.asarray(rgb, np.float64) @ np.array([0.2126, 0.7152, 0.0722])


def sampled_linear(ds) -> np.ndarray:
    """The linear RGB pixels (N, 3) of the centre view of at most :data:`SAMPLED_FRAMES` frames."""
    frames = list(ds.frames)
    if not frames:
        raise LfusdError(f"dataset {ds.root} has no completely rendered frame; finish its render first")
    picks = sorted({frames[int(i)] for i in np.linspace(0, len(frames) - 1, min(SAMPLED_FRAMES, len(frames)))})
    centre = tuple(ds.rig.centre_view)
    return np.concatenate([np.asarray(ds.read(t, centre, "rgb_linear"), np.float32).reshape(-1, 3) for t in picks])


def exposure_figures(ds) -> dict:
    """Brightness of a dataset's images: the 99th percentile of linear luminance, the largest
    linear value, the brightest 1 % in 8-bit sRGB (0-255) and the share of pixels white in every channel."""
    px = sampled_linear(ds)
    finite = px[np.all(np.isfinite(px), axis=-1)]
    lum = _luminance(finite) if len(finite) else np.zeros(1)
    return {"p99_linear": float(np.percentile(lum, BRIGHT_PERCENTILE)), "max_linear": float(finite.max()) if len(finite) else 0.0,
            "p99_8bit": int(np.percentile(linear_to_srgb8(finite).max(axis=-1), BRIGHT_PERCENTILE)) if len(finite) else 0,
            "clipped": float(np.mean(np.all(finite >= 1.0, axis=-1))) if len(finite) else 0.0}


def check_folder(out) -> list[str]:
    """:func:`exposure_problems` of every rig of the dataset in ``out`` (what a render says after it)."""
    from .dataset import open_datasets

    lines = []
    try:
        for ds in open_datasets(out, "all"):
            lines += exposure_problems(ds)
    except LfusdError as e:  # the render's own checks report unreadable files; this one only advises
        log.info("exposure not checked: %s", e)
    return lines


def exposure_problems(ds) -> list[str]:
    """One line per way the dataset's images are far outside a usable range (none when fine, or
    when the render kept no ``rgb_linear`` to look at)."""
    keys = getattr(ds, "keys", None)
    if keys is not None and "rgb_linear" not in keys:
        return []
    f = exposure_figures(ds)
    rig = getattr(ds, "rig_name", "")
    where = f"rig {rig}: " if rig else ""
    gain = auto_gain(ds, f)
    fix = (f"light the stage differently and render again, or export with --exposure auto (one gain for the "
           f"whole dataset, here {gain:.3g}; see the Exposure section of the render command docs)")
    if f["p99_8bit"] < DARK_8BIT:
        return [f"{where}the images are nearly black: the brightest 1 % of pixels reach {f['p99_8bit']}/255 "
                f"(linear {f['p99_linear']:.3g}); {fix}"]
    if f["clipped"] > CLIPPED_SHARE:
        return [f"{where}the images are overexposed: {100 * f['clipped']:.0f} % of pixels are white "
                f"(linear values up to {f['max_linear']:.3g}); {fix}"]
    return []


def auto_gain(ds, figures: dict | None = None) -> float:
    """The automatic exposure of a dataset: the gain on ``rgb_linear`` that puts the brightest
    :data:`BRIGHT_PERCENTILE` % of its sampled pixels at :data:`BRIGHT_TARGET`; 1 for a black dataset."""
    f = figures or exposure_figures(ds)
    return BRIGHT_TARGET / f["p99_linear"] if f["p99_linear"] > 0 else 1.0


class Exposed:
    """A dataset read with ``rgb`` made from ``rgb_linear`` times one ``gain`` (every other key,
    and ``rgb_linear`` itself, as stored); the attributes are the dataset's."""

    def __init__(self, ds, gain: float):
        if not (gain > 0 and np.isfinite(gain)):
            raise LfusdError(f"--exposure {gain}: give a positive gain, or auto")
        self._ds, self.gain = ds, float(gain)

    def __getattr__(self, name):
        return getattr(self._ds, name)

    def read(self, frame, view, key):
        if key == "rgb":
            return linear_to_srgb8(np.asarray(self._ds.read(frame, view, "rgb_linear"), np.float32) * np.float32(self.gain))
        return self._ds.read(frame, view, key)


def exposed(ds, exposure: str) -> Exposed:
    """``ds`` read at ``exposure``: ``auto`` (:func:`auto_gain`) or a gain such as ``4`` or ``0.25``."""
    if exposure == "auto":
        return Exposed(ds, auto_gain(ds))
    try:
        gain = float(exposure)
    except ValueError:
        raise LfusdError(f"--exposure {exposure!r}: give auto or a positive gain such as 4") from None
    return Exposed(ds, gain)
