"""`m3c info`, `m3c export`, `m3c view`: result folders."""

from __future__ import annotations

import sys

from m3c.cli.common import EXIT_INPUT


def info(args) -> int:
    from m3c.io.manifest import folder_state
    from m3c.io.results import PUBLISHED_FILES, describe

    print(describe(args.folder))
    state = folder_state(args.folder, PUBLISHED_FILES)
    if not state.complete:
        print(f"m3c: error: {args.folder}: {state.message}", file=sys.stderr)
        return EXIT_INPUT
    return 0


def export(args) -> int:
    from m3c.export import export_results, parse_track_ids

    try:
        paths = export_results(args.folder, args.format, args.out, parse_track_ids(args.tracks), args.body_model,
                               bvh_unit=args.bvh_unit, rig=args.rig, root_motion=args.root_motion,
                               reference_pose=args.reference_pose, smoothing=args.smoothing,
                               foot_lock=args.foot_lock)
    except PermissionError as err:  # an unwritable --out: bad input, not a bug
        raise ValueError(str(err)) from None
    for path in paths:
        print(path)
    return 0


def view(args) -> int:
    from m3c.viz.viewer import serve

    serve(args.folder, host=args.host, port=args.port, body_model=args.body_model, video=args.video)
    return 0
