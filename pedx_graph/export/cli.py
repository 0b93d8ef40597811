"""``pedx-graph export``: meshes, overlays, top views and animations of a results folder."""
from __future__ import annotations

import argparse


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export", help="meshes (PLY/OBJ), overlays on the images, top views and a GIF per track of a fit",
        description="Write RESULTS' fitted bodies as per-frame meshes, draw them with their keypoints and 95 % "
                    "uncertainty ellipses over the camera images (a blank canvas where images/ is absent), draw "
                    "each track from above in the level frame of the derived ground with its position "
                    "ellipses, and animate each track.  Index: OUT/export.json.")
    p.add_argument("results", metavar="RESULTS", help="results folder (pedx-graph fit / stream output)")
    p.add_argument("--dataset", default=None,
                   help="the dataset that was fitted (calibration, 2D labels, images/); default: the path "
                        "summary.json records, when it exists")
    p.add_argument("--out", default=None, help="output folder (default: RESULTS/export)")
    p.add_argument("--frame", choices=("lidar", "world"), default="lidar",
                   help="frame of the meshes: lidar (as the results) or world (level frame of the derived "
                        "ground: its z is the derived up, ground at z = 0) (default: %(default)s)")
    p.add_argument("--formats", default="ply,obj", help="mesh formats, comma-separated (default: %(default)s)")
    p.add_argument("--tracks", default="", help="comma-separated tracking ids (prefixes) to export (default: all)")
    p.add_argument("--every", type=int, default=1, help="overlay every n-th frame (default: %(default)s)")
    p.add_argument("--scale", type=float, default=1.0,
                   help="overlay size relative to the calibration's image size (default: %(default)s)")
    p.add_argument("--fps", type=float, default=5.0, help="frames per second of the animations (default: %(default)s)")
    p.add_argument("--no-meshes", action="store_true", help="skip the meshes")
    p.add_argument("--no-overlays", action="store_true", help="skip the overlays")
    p.add_argument("--no-gif", action="store_true", help="skip the animations")
    p.add_argument("--model", default=None, help="body model file (default: fit_config.yaml's, else the open model)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pedx_graph.export.run import ExportConfig, export_results

    if args.every < 1 or not args.scale > 0 or not args.fps > 0:
        raise ValueError("--every must be >= 1 and --scale, --fps > 0")
    config = ExportConfig(frame=args.frame, formats=tuple(f.strip() for f in args.formats.split(",") if f.strip()),
                          meshes=not args.no_meshes, overlays=not args.no_overlays, overlay_every=args.every,
                          overlay_scale=args.scale, animations=not args.no_gif, fps=args.fps,
                          tracks=tuple(t.strip() for t in args.tracks.split(",") if t.strip()))
    record = export_results(args.results, args.out, args.dataset, config, args.model, progress=True)
    files = ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in record["files"].items())
    out = args.out or f"{args.results}/export"
    print(f"exported {len(record['tracks'])} tracks in {record['seconds']:.1f} s: {files} -> {out} "
          f"(index: export.json)")
    for note in record["notes"]:
        print(f"note: {note}")
    return 0
