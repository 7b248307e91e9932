"""`lfusd dataset make RECIPE.toml -o DIR`: generate, render, verify and describe a dataset (lfusd.recipe)."""

from __future__ import annotations

from pathlib import Path

from . import args as argtypes


def register(sub) -> None:
    p = sub.add_parser("dataset", help="make a whole dataset from a recipe (scenes, rigs, renders, verification, card)")
    dsub = p.add_subparsers(dest="dataset_command", metavar="ACTION")
    m = dsub.add_parser("make", help="make or finish the dataset of a recipe (resumable: done, verified scenes are skipped)",
                        description="Generate the recipe's scenes, render, verify and write DIR/CARD.md, DIR/card.json and DIR/plots/.")
    m.add_argument("recipe", help="the recipe, a TOML file (see recipes/default.toml)")
    m.add_argument("-o", "--out", required=True, metavar="DIR", help="dataset folder (created; rerunning the same recipe resumes)")
    m.add_argument("--quiet", action="store_true", help="no progress bars from the renders")
    m.set_defaults(func=run_make)
    p.set_defaults(func=argtypes.run_help(p))


def run_make(args) -> int:
    from ..recipe import make_dataset

    def progress(i, n, scene, action):
        print(f"lfusd: scene {i + 1}/{n} {scene}: {'complete and verified, skipped' if action == 'skip' else 'making'}", flush=True)

    res = make_dataset(args.recipe, args.out, quiet=args.quiet, progress=progress)
    card = res.card
    d = card["disparity"]
    rng = f"{d['min']:.3g}-{d['max']:.3g} px" if d["pixels"] else "none"
    print(f"lfusd: {Path(args.out) / 'CARD.md'}: {len(res.scenes)} scenes ({len(res.made)} made, {len(res.skipped)} skipped), "
          f"disparity {rng}, {card['pixels']} pixels measured, verification {'passed' if card['verified'] else 'FAILED'}")
    if res.failed:
        print(f"lfusd: verification failed for {', '.join(res.failed)}; see their scenes/<scene>.json")
    return 0 if card["verified"] else 1
