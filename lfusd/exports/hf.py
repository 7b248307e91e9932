"""A Hugging Face dataset folder (``lfusd export hf``): the WebDataset export
(:mod:`lfusd.exports.webdataset`) plus a dataset card ``README.md`` whose YAML header points
``datasets.load_dataset`` at the shards."""

from __future__ import annotations

from pathlib import Path

from .registry import TEXT, Option, register


@register("hf", "the webdataset export plus a Hugging Face dataset card", unit="shard",
          options=(Option("--license", "license", TEXT, "the data's license (SPDX id or URL) for the metadata (default: none claimed)"),))
def export_hf(ds, dest, frame: int | None = None, views=None, license: str | None = None) -> list[Path]:
    """:func:`lfusd.exports.webdataset.export_webdataset` plus the Hugging Face dataset card (``datasets.load_dataset(dest)``)."""
    from .webdataset import export_webdataset  # imported here: webdataset registers after hf

    return export_webdataset(ds, dest, frame=frame, views=views, hf=True, license=license)
