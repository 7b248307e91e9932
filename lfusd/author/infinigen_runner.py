"""Run one Infinigen factory and export its asset to USD: the script `lfusd assets bake` starts.

It runs in Infinigen's own environment (``.venv-infinigen``, made by scripts/setup_infinigen.sh:
CPython 3.11 with bpy 4.2 and infinigen 1.15.5), never in lfusd's: lfusd starts it as
``PYTHON infinigen_runner.py --factory F --seed N --out DIR`` and imports nothing of it. It uses
only Infinigen, its bpy and the standard library (no lfusd, no usd-core).

Infinigen's asset modules ask Blender for add-ons (rocks, snow, landscapes) when imported and,
when one is missing, go on to download it from extensions.blender.org even when told not to (a
"warn" failure falls through to the online install). The runner switches Blender's online
access off and replaces that request with a local-only one before any asset module is imported.

The last stdout line is ``LFUSD_BAKE {"usd": ..., "seconds": ...}`` (JSON); a failure is one line
on stderr and exit status 2 (factory not found) or 1.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import sys
import time
from pathlib import Path

log = logging.getLogger("lfusd.infinigen_runner")
# Run as a script, its folder (lfusd/author) comes first on the module path, where lfusd's modules
# (geometry, labels, stage, ...) would shadow the names Infinigen's dependencies import.
if sys.path and Path(sys.path[0] or ".").resolve() == Path(__file__).resolve().parent:
    sys.path.pop(0)


def _offline() -> None:
    import bpy  # before addon_utils, which Blender's module puts on the path

    import addon_utils

    bpy.context.preferences.system.use_online_access = False
    from infinigen.core import init

    def require_blender_addon(addon: str, fail: str = "fatal", allow_online: bool = False) -> bool:
        long = f"bl_ext.blender_org.{addon}"
        if long in bpy.context.preferences.addons.keys():
            return True
        local = {m.__name__ for m in addon_utils.modules(refresh=False)}
        for name in (long, addon):
            if name in local:
                bpy.ops.preferences.addon_enable(module=name)
                return True
        msg = f"Blender add-on {addon} is not installed and lfusd bakes offline"
        if fail == "fatal":
            raise ValueError(msg)
        log.warning("%s; factories that need it will fail", msg)
        return False

    init.require_blender_addon = require_blender_addon


def _modules():
    """Infinigen's asset modules (infinigen.assets.objects.*, as its generate_individual_assets
    walks them), each imported; one that fails to import is skipped with a warning."""
    import gin
    import infinigen.assets.objects as objects

    for sub in sorted(Path(next(iter(objects.__path__))).iterdir()):
        if sub.name.startswith("_") or not (sub.is_dir() or sub.suffix == ".py"):
            continue
        with gin.unlock_config():
            try:
                yield importlib.import_module(f"infinigen.assets.objects.{sub.name.split('.')[0]}")
            except Exception as e:  # one broken module (a missing add-on) must not hide the others
                log.warning("skipping infinigen.assets.objects.%s: %s", sub.name, e)


def _factory(name: str):
    """The factory class ``name`` from Infinigen's asset modules, or None."""
    return next((getattr(m, name) for m in _modules() if hasattr(m, name)), None)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--factory")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", type=Path)
    p.add_argument("--texture-size", type=int, default=1024)
    p.add_argument("--check", action="store_true", help="only import every asset module offline, count the factories")
    a = p.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    start = time.monotonic()
    _offline()
    if a.check:
        import bpy

        modules = list(_modules())
        factories = {n for m in modules for n in dir(m) if n.endswith("Factory")}
        print("LFUSD_BAKE " + json.dumps({"bpy": bpy.app.version_string, "modules": len(modules), "factories": len(factories)}))
        return 0
    if not (a.factory and a.out):
        p.error("--factory and --out are required")
    from infinigen.core import init
    from infinigen.core.util import blender as butil
    from infinigen.core.util.math import FixedSeed
    from infinigen.tools import export

    # Infinigen's own defaults (its base.gin), as its generate_individual_assets applies them
    init.apply_gin_configs(["infinigen_examples/configs_indoor", "infinigen_examples/configs_nature"], skip_unknown=True)
    init.configure_blender()
    butil.clear_scene()
    factory = _factory(a.factory)
    if factory is None:
        print(f"Infinigen has no asset factory {a.factory} in infinigen.assets.objects; give a factory class name "
              "such as ChairFactory or TableDiningFactory", file=sys.stderr)
        return 2
    with FixedSeed(a.seed):
        fac = factory(a.seed)
        # Nothing else is removed: the factory's hidden collections (a bush's twigs and flowers) are
        # what its geometry nodes instance, and the exporter writes only what renders.
        fac.finalize_assets(fac.spawn_asset(a.seed))
    a.out.mkdir(parents=True, exist_ok=True)
    usd = export.export_curr_scene(a.out, format="usdc", image_res=a.texture_size)
    print("LFUSD_BAKE " + json.dumps({"usd": str(Path(usd).resolve()), "seconds": round(time.monotonic() - start, 1)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
