"""Regenerate every committed template stage from the template, seed and sizes it records.

Run after a change to the scene library: ``python stages/regenerate.py``. The test suite
regenerates them the same way and compares bytes (tests/author/test_scenes.py).
"""

from __future__ import annotations

from pathlib import Path

from pxr import Usd

from lfusd.author import vocabulary as vocab
from lfusd.author.scenes import generate
from lfusd.author.rigs import rigs

HERE = Path(__file__).resolve().parent


def recorded_arguments(path: Path) -> tuple[str, int, dict]:
    """(template, seed, keyword arguments of ``generate``) as recorded in a generated stage."""
    stage = Usd.Stage.Open(str(path))
    world = stage.GetDefaultPrim()
    found = rigs(stage)
    spec = found["rig_00"].spec
    return (world.GetCustomDataByKey(vocab.TEMPLATE), int(world.GetCustomDataByKey(vocab.SEED)),
            dict(frames=int(stage.GetEndTimeCode()), rigs=len(found), grid=(spec.rows, spec.cols),
                 resolution=(spec.width, spec.height), dynamic=bool(world.GetCustomDataByKey(vocab.DYNAMIC))))


def committed_stages() -> list[Path]:
    return sorted(p for p in HERE.glob("*.usda") if p.name != "static_boxes.usda")


if __name__ == "__main__":
    for path in committed_stages():
        template, seed, kwargs = recorded_arguments(path)
        generate(template, path, seed, **kwargs)
        print(f"regenerated {path.name} ({template}, seed {seed})")
