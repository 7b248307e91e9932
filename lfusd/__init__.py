"""lfusd: light-field video datasets with exact ground truth, from OpenUSD stages rendered in Blender.

The pipeline steps, one library function each (the `lfusd` commands call the same functions)::

    lfusd.generate(template, path, seed)          # lfusd stage new
    lfusd.add_rig(stage, RigSpec(...))            # lfusd rig add
    lfusd.add_person(stage, points, ...)          # lfusd animate add-person
    lfusd.render_frame(RenderRequest(...))        # lfusd render
    lfusd.render_video(...)                       # lfusd render-video
    lfusd.derive(out, rigs, frames)               # lfusd derive
    lfusd.verify(out)                             # lfusd verify
    lfusd.export(Dataset(out), "hci", dest)       # lfusd export
    lfusd.evaluate(out, pred_dir, "disparity")    # lfusd eval
    lfusd.Dataset(out)                            # read a dataset

They are imported on first use, so ``import lfusd`` stays light (no pxr, bpy or torch).
"""

__version__ = "0.1.0"

from .errors import LfusdError

# Facade name -> (module, attribute).
_LAZY = {
    "Dataset": ("lfusd.data.dataset", "Dataset"),
    "generate": ("lfusd.author.scenes", "generate"),
    "add_rig": ("lfusd.author.rigs", "add_rig"),
    "add_person": ("lfusd.author.people", "add_person"),
    "render_frame": ("lfusd.render.job", "render"),
    "render_video": ("lfusd.render.job", "render_video"),
    "derive": ("lfusd.truth.derive", "derive_dataset"),
    "verify": ("lfusd.truth.verify", "verify"),
    "export": ("lfusd.exports", "export"),
    "evaluate": ("lfusd.evaluation.score", "evaluate"),
}

__all__ = ["LfusdError", "__version__", *_LAZY]  # noqa: PLE0604 (_LAZY's keys are the names)


def __getattr__(name):
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        return getattr(importlib.import_module(module), attr)
    raise AttributeError(f"module 'lfusd' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
