"""What a render asks for: the request `lfusd render` and `render-video` build, and its checks."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from ..errors import LfusdError

DEVICES = ("auto", "cpu", "cuda", "optix")
EXECUTORS = ("local", "ray")
LIGHTS = ("auto", "none")  # auto: a stage without lights gets a neutral sky and sun; none: nothing added


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
    quiet: bool = False
    executor: str = "local"
    ray_address: str | None = None
    frames_per_unit: int = 10
    motion: bool = False  # also render the t+/-1 position AOVs (render-video)
    light: str = "auto"  # one of LIGHTS
    extra_settings: dict = field(default_factory=dict)

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
