"""A camera sensor after the renderer: the noisy sRGB image (key ``rgb_noisy``) of a view, computed from
its clean linear image (``rgb_linear``) by a documented model, the same for a seed on any machine that
runs the same NumPy (the clean image stays; see docs/CONVENTIONS.md, "Sensor model").

Per view (camera ``(row, col)`` of a rig), drawn once from the seed and the view, as a real array's
cameras differ and keep their differences from frame to frame:

- gain ``g``: log-normal, ``exp(N(0, gain_spread))``;
- colour response ``c`` (3,): per-channel gains ``exp(N(0, colour_spread))`` (a white-balance error);
- vignetting ``v(r) = 1 - k r^2``, ``r`` the distance from the image centre over the half diagonal,
  ``k = vignetting * exp(N(0, 0.2))`` clipped to [0, 0.95].

Per pixel and channel, with ``x`` the clean linear value and ``s = g * c * v * x`` (``x < 0`` taken as 0),
the sensor counts ``Q = full_well * 100 / iso`` electrons per unit of output (ISO 100 fills the well at
1.0) and adds read noise of ``read_noise`` electrons:

    y = Poisson(Q s) / Q + N(0, (read_noise / Q)^2),  so  E[y] = s,  Var[y] = s / Q + (read_noise / Q)^2

(the Poisson-Gaussian model of Foi et al. 2008), with fresh noise per frame. The image is then clipped
to [0, 1] (saturation), sRGB-encoded to 8 bits (lfusd.data.passes.linear_to_srgb8) and, with ``jpeg``
a quality in 1-100, JPEG-compressed and decoded (OpenCV's libjpeg, 4:2:0).

Pure NumPy (OpenCV for the JPEG); no pxr, bpy or torch.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from ..errors import LfusdError

VIGNETTING_SPREAD = 0.2  # log-normal sigma of k across the cameras of a rig
MAX_VIGNETTING = 0.95


@dataclass(frozen=True)
class SensorModel:
    """The parameters of the model in the module docstring (manifest ``settings.sensor``)."""

    iso: float = 100.0
    full_well: float = 10000.0  # electrons at linear 1.0 and ISO 100
    read_noise: float = 3.0  # electrons, standard deviation
    gain_spread: float = 0.05
    colour_spread: float = 0.03
    vignetting: float = 0.3
    jpeg: int = 0  # JPEG quality 1-100; 0: no JPEG
    seed: int = 0

    def check(self) -> "SensorModel":
        """This model, or LfusdError naming the first impossible parameter and its range."""
        bad = next(((name, fix) for name, ok, fix in (
            ("iso", self.iso > 0, "a positive number such as 100 or 1600"),
            ("full_well", self.full_well > 0, "positive electrons"),
            ("read_noise", self.read_noise >= 0, "electrons >= 0"),
            ("gain_spread", self.gain_spread >= 0, ">= 0"),
            ("colour_spread", self.colour_spread >= 0, ">= 0"),
            ("vignetting", 0 <= self.vignetting <= MAX_VIGNETTING, f"in 0-{MAX_VIGNETTING}"),
            ("jpeg", isinstance(self.jpeg, int) and 0 <= self.jpeg <= 100, "a quality in 1-100, or 0 for none"),
            ("seed", isinstance(self.seed, int) and self.seed >= 0, "an integer >= 0"),
        ) if not (ok and math.isfinite(float(getattr(self, name))))), None)
        if bad:
            raise LfusdError(f"sensor {bad[0]} {getattr(self, bad[0])!r} is impossible; use {bad[1]}")
        return self

    @property
    def electrons_per_unit(self) -> float:
        """Q: electrons per unit of linear output at this ISO."""
        return self.full_well * 100.0 / self.iso

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, doc: dict) -> "SensorModel":
        """The model recorded in a manifest (LfusdError where it is not one)."""
        try:
            return cls(**{k: (int if k in ("jpeg", "seed") else float)(v) for k, v in doc.items()}).check()
        except (TypeError, ValueError):
            raise LfusdError(f"the sensor record {doc!r} is not an lfusd sensor model; render the dataset again") from None


@dataclass(frozen=True)
class ViewResponse:
    """One camera's fixed response: gain, per-channel colour gains and vignetting coefficient."""

    gain: float
    colour: np.ndarray  # (3,)
    vignetting: float

    def vignette(self, height: int, width: int) -> np.ndarray:
        """v (H,W) float64 at the pixel centres."""
        v, u = np.mgrid[0:height, 0:width].astype(np.float64)
        r2 = ((u + 0.5 - width / 2) ** 2 + (v + 0.5 - height / 2) ** 2) / ((width / 2) ** 2 + (height / 2) ** 2)
        return 1.0 - self.vignetting * r2

    def scale(self, height: int, width: int) -> np.ndarray:
        """g * c * v: the factor (H,W,3) between the clean image and the mean of the noisy one."""
        return self.gain * self.vignette(height, width)[..., None] * self.colour


def _u32(x: int) -> int:
    return int(x) % (1 << 32)  # SeedSequence takes non-negative entropy; frames may be negative


def view_response(model: SensorModel, view: tuple[int, int]) -> ViewResponse:
    """The fixed response of camera ``view`` (row, col), drawn from the seed and the view."""
    rng = np.random.default_rng([_u32(model.seed), 0, _u32(view[0]), _u32(view[1])])
    gain = float(np.exp(rng.normal(0.0, model.gain_spread)))
    colour = np.exp(rng.normal(0.0, model.colour_spread, 3))
    k = float(np.clip(model.vignetting * np.exp(rng.normal(0.0, VIGNETTING_SPREAD)), 0.0, MAX_VIGNETTING))
    return ViewResponse(gain, colour, k)


def expose(model: SensorModel, linear: np.ndarray, view: tuple[int, int], frame: int) -> np.ndarray:
    """The noisy linear signal y (H,W,3) float64 before saturation, of the model in the module docstring."""
    linear = np.asarray(linear, np.float64)
    h, w = linear.shape[:2]
    s = np.maximum(np.nan_to_num(linear, nan=0.0, posinf=0.0), 0.0) * view_response(model, view).scale(h, w)
    rng = np.random.default_rng([_u32(model.seed), 1, _u32(view[0]), _u32(view[1]), _u32(frame)])
    q = model.electrons_per_unit
    return rng.poisson(s * q) / q + rng.normal(0.0, model.read_noise / q, s.shape)


def moments(model: SensorModel, s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """The model's mean and variance of y for a mean signal ``s`` (after gain, colour and vignetting)."""
    q = model.electrons_per_unit
    s = np.asarray(s, np.float64)
    return s, s / q + (model.read_noise / q) ** 2


def noisy_srgb(model: SensorModel, linear: np.ndarray, view: tuple[int, int], frame: int) -> np.ndarray:
    """The ``rgb_noisy`` key: (H,W,3) uint8 sRGB of the sensor's image of ``linear`` at ``frame``."""
    from .passes import linear_to_srgb8

    image = linear_to_srgb8(np.clip(expose(model, linear, view, frame), 0.0, 1.0).astype(np.float32))
    if model.jpeg:
        import cv2

        ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(image[..., ::-1]), [cv2.IMWRITE_JPEG_QUALITY, model.jpeg])
        if not ok:
            raise LfusdError("OpenCV could not JPEG-encode the noisy image; reinstall opencv-python")
        image = np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])
    return image
