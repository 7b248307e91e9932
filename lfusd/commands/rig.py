"""`lfusd rig add`: write a light-field rig into a stage."""

from __future__ import annotations

from ..camera import AXES, LAYOUTS, SPACINGS, RigSpec
from . import args as argtypes


def register(sub) -> None:
    rig = sub.add_parser("rig", help="author light-field rigs in a stage")
    rsub = rig.add_subparsers(dest="rig_command", metavar="ACTION", required=True)
    add = rsub.add_parser("add", help="add a rig of UsdGeom.Camera prims to a stage")
    d = RigSpec()
    add.add_argument("stage", help="the USD stage or asset (.usda/.usdc/.usdz/.usd); edited in place unless -o is given")
    add.add_argument("-o", "--out", default=None, metavar="NEW.usda",
                     help="write a new layer that sublayers STAGE (left unchanged) and holds the rig; needed for .usdz packages")
    add.add_argument("--name", default="main", help="rig prim name (default: main)")
    add.add_argument("--grid", type=argtypes.grid, default=f"{d.rows}x{d.cols}", help="views as ROWSxCOLS (default 9x9)")
    add.add_argument("--baseline", type=float, default=d.baseline, help="metres between neighbouring cameras (default 0.125)")
    add.add_argument("--focal-length", type=float, default=None, help=f"lens in mm (default {d.focal_length_mm:g})")
    add.add_argument("--sensor", type=float, default=None, help=f"sensor width in mm (default {d.sensor_mm:g})")
    add.add_argument("--resolution", type=argtypes.resolution, default=None,
                     help=f"WIDTHxHEIGHT pixels (default {d.width}x{d.height}; with --from-camera {d.width} wide at the camera's aspect)")
    add.add_argument("--from-camera", default=None, metavar="PRIM",
                     help="centre the rig on the stage's own UsdGeom.Camera PRIM: its pose (animated too), focal length and aperture")
    add.add_argument("--at", type=argtypes.point, default=None,
                     help="rig centre X,Y,Z: metres along the stage's own axes, its up axis the rig's up "
                          f"(default: {d.at[2]:g} m up, {-d.at[1]:g} m back from the origin)")
    add.add_argument("--look-at", type=argtypes.point, default=None,
                     help=f"point X,Y,Z the rig looks at (metres, stage axes; default: {d.look_at[2]:g} m above the origin)")
    add.add_argument("--spacing", default=d.spacing, help=f"{'|'.join(SPACINGS)} (default uniform)")
    add.add_argument("--layout", default=d.layout, help=f"{'|'.join(LAYOUTS)} (default plane)")
    add.add_argument("--radius", type=float, default=None, help="sphere radius in metres (default: distance to --look-at)")
    add.add_argument("--axes", default=None, help=f"{'|'.join(AXES)} (default parallel; converge for sphere)")
    add.add_argument("--force", action="store_true", help="allow grids and resolutions beyond the limits (4096 views, 16384x16384)")
    add.set_defaults(func=run_add)


def run_add(args) -> int:
    from ..author.rigs import add_rig_to_file

    spec, target = add_rig_to_file(
        args.stage, args.out, name=args.name, grid=args.grid, baseline=args.baseline, focal_length_mm=args.focal_length,
        sensor_mm=args.sensor, resolution=args.resolution, at=args.at, look_at=args.look_at, spacing=args.spacing,
        layout=args.layout, radius=args.radius, axes=args.axes, from_camera=args.from_camera, force=args.force)
    over = f" (a new layer over {args.stage})" if args.out else ""
    cam = f", centre view at camera {args.from_camera} ({spec.focal_length_mm:g} mm lens, {spec.sensor_mm:g} mm aperture)" if args.from_camera else ""
    print(f"added rig {spec.name} ({spec.rows}x{spec.cols} views, {spec.width}x{spec.height} px){cam} to {target}{over}")
    return 0
