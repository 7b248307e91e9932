"""lfusd: light-field video datasets with exact ground truth, from OpenUSD stages rendered in Blender."""

__version__ = "0.1.0"
__all__ = ["Dataset", "LfusdError", "__version__"]

from .errors import LfusdError


def __getattr__(name):
    # Dataset pulls in OpenEXR; keep `import lfusd` light for the CLI and authoring code.
    if name == "Dataset":
        from .data.dataset import Dataset

        return Dataset
    raise AttributeError(name)
