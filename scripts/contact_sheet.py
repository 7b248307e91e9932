"""Render one frame of committed stages at 512x512 and build the README's contact sheet.

    python scripts/contact_sheet.py render STAGE... --out DIR [--frame N] [--samples S]
    python scripts/contact_sheet.py sheet --before DIR --after DIR -o docs/looks_before_after.png

``render`` lays a one-view rig (``contact``: rig_00's centre view, 512x512) over each stage in a
new layer beside it in DIR (the stage itself is not touched) and renders it with ``lfusd.render``;
``sheet`` puts the renders of two such folders side by side, one row per stage (before, after).
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

SIZE = 512
RIG = "contact"


def render(stage_path: Path, out: Path, frame: int, samples: int) -> Path:
    """Render ``frame`` of ``stage_path`` through rig_00's centre view at SIZE x SIZE; return the PNG."""
    from lfusd import Dataset
    from lfusd.author.rigs import add_rig, rigs
    from lfusd.author.stage import layer_over
    from lfusd.render.job import render as render_stage
    from lfusd.render.request import RenderRequest

    out.mkdir(parents=True, exist_ok=True)
    layer = out / f"{stage_path.stem}_contact.usda"
    if layer.exists():
        layer.unlink()
    stage = layer_over(stage_path.resolve(), layer)
    spec = rigs(stage)["rig_00"].spec
    add_rig(stage, replace(spec, name=RIG, rows=1, cols=1, width=SIZE, height=SIZE))
    stage.GetRootLayer().Save()
    data = out / f"{stage_path.stem}_data"
    start = time.perf_counter()
    render_stage(RenderRequest(stage=layer, out=data, rig=RIG, frames=[frame], samples=samples, keys=("rgb",),
                               overwrite=True, quiet=True))
    print(f"{stage_path.name}: frame {frame}, {SIZE}x{SIZE}, {samples} samples: {time.perf_counter() - start:.1f} s")
    png = out / f"{stage_path.stem}.png"
    Image.fromarray(Dataset(data, rig=RIG).read(frame, (0, 0), "rgb")).save(png)
    return png


def sheet(before: Path, after: Path, output: Path, names: list[str] | None = None) -> None:
    """One row per stage rendered in both folders: before | after, labelled."""
    names = names or sorted(p.stem for p in before.glob("*.png") if (after / p.name).exists())
    if not names:
        raise SystemExit(f"no PNG rendered in both {before} and {after}")
    pad, label = 8, 22
    w, h = 2 * SIZE + 3 * pad, len(names) * (SIZE + label + pad) + pad
    canvas = Image.new("RGB", (w, h), (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    for row, name in enumerate(names):
        y = pad + row * (SIZE + label + pad)
        for col, (folder, title) in enumerate(((before, "before"), (after, "after"))):
            x = pad + col * (SIZE + pad)
            draw.text((x, y + 4), f"{name}: {title}", fill=(0, 0, 0))
            canvas.paste(Image.open(folder / f"{name}.png").convert("RGB"), (x, y + label))
    output.parent.mkdir(parents=True, exist_ok=True)
    # 6 bits per channel: the renders' sampling noise would otherwise take the PNG past 1.5 MB
    pixels = np.asarray(canvas) >> 2 << 2 | 2
    Image.fromarray(pixels.astype(np.uint8)).save(output, optimize=True)
    print(f"wrote {output} ({output.stat().st_size / 1e6:.2f} MB)")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("render")
    r.add_argument("stages", nargs="+", type=Path)
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--frame", type=int, default=None, help="default: the middle of the stage's frames")
    r.add_argument("--samples", type=int, default=32)
    s = sub.add_parser("sheet")
    s.add_argument("--before", type=Path, required=True)
    s.add_argument("--after", type=Path, required=True)
    s.add_argument("-o", "--output", type=Path, required=True)
    s.add_argument("--names", nargs="*")
    a = p.parse_args()
    if a.cmd == "render":
        from lfusd.author.stage import frame_range, open_stage

        for path in a.stages:
            first, last = frame_range(open_stage(path))
            render(path, a.out, a.frame if a.frame is not None else (first + last) // 2, a.samples)
    else:
        sheet(a.before, a.after, a.output, a.names)


if __name__ == "__main__":
    main()
