"""`lfusd bench make|oracle|score|baseline`: the light-field video scene-flow benchmark (lfusd.bench)."""

from __future__ import annotations

from pathlib import Path

from . import args as argtypes


def register(sub) -> None:
    from ..bench.make import definition_names
    from ..recipe import EXECUTORS
    from ..render.request import DEVICES

    p = sub.add_parser("bench", help="the light-field video scene-flow benchmark: make, oracle, score, baseline")
    bsub = p.add_subparsers(dest="bench_command", metavar="ACTION")
    m = bsub.add_parser("make", help="render a frozen benchmark and write its public/ and gt/ folders (resumable)",
                        description="Generate the definition's stages (refused when they differ from its frozen digests), render and verify "
                                    "every scene, then write DIR/public/ (train and val with ground truth, test with rgb and cameras only), "
                                    "DIR/gt/ (the test ground truth and its digests) and the cards.")
    m.add_argument("name", choices=definition_names(), help="the benchmark definition (lfusd/bench/definitions/NAME.toml)")
    m.add_argument("-o", "--out", required=True, metavar="DIR", help="benchmark folder (created; rerunning the same definition resumes)")
    m.add_argument("--executor", default=None, choices=EXECUTORS, help="render with local processes or on Ray (default: the definition's)")
    m.add_argument("--ray-address", default=None, help="join this Ray cluster (with --executor ray)")
    m.add_argument("--workers", type=int, default=None, help="Blender worker processes / Ray task slots (default: the definition's)")
    m.add_argument("--device", default=None, choices=DEVICES, help="Cycles device (default: the definition's)")
    m.add_argument("--quiet", action="store_true", help="no progress bars from the renders")
    m.set_defaults(func=run_make)
    o = bsub.add_parser("oracle", help="write the test ground truth as a submission (to check the format and the scorer)")
    o.add_argument("bench", metavar="DIR", help="benchmark folder (`lfusd bench make -o DIR`)")
    o.add_argument("-o", "--out", required=True, metavar="SUB", help="submission folder to write")
    o.set_defaults(func=run_oracle)
    s = bsub.add_parser("score", help="score a submission on the test split: JSON, CSV and a Markdown leaderboard row",
                        description="Score every view of every scored test frame; check gt/ against its digests first. "
                                    "Writes score.json, score.csv and leaderboard.md (default into SUBMISSION).")
    s.add_argument("submission", metavar="SUBMISSION", help="folder of <scene>/<frame>_<row>_<col>.npz")
    s.add_argument("--bench", required=True, metavar="DIR", help="benchmark folder (`lfusd bench make -o DIR`)")
    s.add_argument("--out", default=None, metavar="FOLDER", help="where to write the results (default: SUBMISSION)")
    s.add_argument("--method", default=None, help="the method's name in the leaderboard row (default: the submission folder's name)")
    s.set_defaults(func=run_score)
    b = bsub.add_parser("baseline", help="a baseline's submission: (a) DIS flow + plane-sweep disparity, or (b) ray flow (Ma et al. 2018)",
                        description="Reads only DIR/public/test (rgb and cameras) and writes a submission to SUB.")
    b.add_argument("bench", metavar="DIR", help="benchmark folder (`lfusd bench make -o DIR`)")
    b.add_argument("-o", "--out", required=True, metavar="SUB", help="submission folder to write")
    b.add_argument("--planes", type=int, default=48, help="disparity planes of the sweep (default 48)")
    b.add_argument("--window", type=int, default=9, help="cost aggregation window of the sweep in pixels (default 9)")
    b.add_argument("--device", default=None, help="torch device (default: cuda if available, else cpu)")
    b.add_argument("--method", choices=("dis", "rayflow"), default="dis",
                   help="dis: baseline (a), DIS flow + plane sweep; rayflow: baseline (b), the ray flow of Ma, Smith & Gupta "
                        "(ECCV 2018) from the light-field gradients of every view (default dis)")
    b.add_argument("--solver", choices=("local", "global"), default="global",
                   help="ray flow's solver: local (Lucas-Kanade window) or global (that window's data term with a structure-aware "
                        "Horn-Schunck smoothness) (default global)")
    b.set_defaults(func=run_baseline)
    p.set_defaults(func=argtypes.run_help(p))


def run_make(args) -> int:
    from ..bench.make import make_bench

    def progress(i, n, scene, action):
        print(f"lfusd: scene {i + 1}/{n} {scene}: {'complete and verified, skipped' if action == 'skip' else 'making'}", flush=True)

    res = make_bench(args.name, args.out, quiet=args.quiet, progress=progress, executor=args.executor, ray_address=args.ray_address,
                     workers=args.workers, device=args.device)
    sp = res.record["splits"]
    print(f"lfusd: {Path(args.out)}: benchmark {args.name}, {len(sp['train'])} train, {len(sp['val'])} val, {len(sp['test'])} test scenes "
          f"({len(res.made)} rendered, {len(res.skipped)} skipped); publish {Path(args.out) / 'public'}, keep {Path(args.out) / 'gt'} private")
    return 0


def run_oracle(args) -> int:
    from ..bench.score import write_oracle

    n = write_oracle(args.bench, args.out)
    print(f"lfusd: {args.out}: {n} files (the test ground truth as a submission)")
    return 0


def run_score(args) -> int:
    from ..bench.score import leaderboard_header, leaderboard_row, score_submission, write_results

    res = score_submission(args.submission, args.bench)
    method = args.method or Path(args.submission).resolve().name
    paths = write_results(res, Path(args.out or args.submission), method)
    print(leaderboard_header())
    print(leaderboard_row(res, method))
    print(f"lfusd: {paths['json']}, {paths['csv']}, {paths['md']}")
    return 0


def run_baseline(args) -> int:
    from ..bench.baseline import write_baseline

    n = write_baseline(args.bench, args.out, n_planes=args.planes, window=args.window, device=args.device, method=args.method, solver=args.solver)
    what = "baseline a: DIS flow + plane-sweep disparity" if args.method == "dis" else f"baseline b: ray flow, {args.solver} solver"
    print(f"lfusd: {args.out}: {n} files ({what})")
    return 0
