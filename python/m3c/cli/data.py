"""`m3c data mocap`: training data from motion capture."""

from __future__ import annotations

from pathlib import Path

from m3c.cli.common import log_to_stderr, output_folder


def data_mocap(args) -> int:
    from m3c.body import default_body_model
    import json

    from m3c.io.atomic import atomic_path
    from m3c.mocap.corpus import (BENCHMARK_CLIP_NAMES, CorpusConfig, build_corpus, corpus_coverage,
                                  load_corpus)
    from m3c.mocap.fast_retarget import FastRetargetConfig

    out = output_folder(args.out)
    if args.workers < 1:
        raise ValueError(f"--workers must be at least 1, got {args.workers}")
    if not 0 <= args.held_out <= 100:
        raise ValueError(f"--held-out must be a percentage in [0, 100], got {args.held_out}")
    exclude = set(BENCHMARK_CLIP_NAMES)
    for item in args.exclude or []:
        path = Path(item)
        exclude |= ({p.stem for p in path.rglob("*.bvh")} if path.is_dir()
                    else {path.name.removesuffix(".bvh")})
    model = default_body_model(args.body_model)
    config = CorpusConfig(retarget=FastRetargetConfig(fps=args.fps), held_out_percent=args.held_out,
                          exclude=frozenset(exclude))
    index = build_corpus(args.corpus, out, model, config, workers=args.workers,
                         model_file=args.body_model or "", log=None if args.quiet else log_to_stderr,
                         limit=args.limit)
    clips, failed = index["clips"], index["failed"]
    held = sum(c["split"] == "held_out" for c in clips.values())
    print(f"wrote {out}: {len(clips)} clips ({held} held out), {index['frames']} frames "
          f"({index['frames'] / index['fps'] / 3600:.2f} h at {index['fps']:g} fps), {len(failed)} failed, "
          f"{len(index['excluded_benchmark_clips'])} benchmark clips left out, {index['seconds']:.0f} s")
    for clip, why in failed.items():
        print(f"  failed {clip}: {why['error']}")
    if clips:
        # What the corpus covers (locomotion dominates motion capture): written into index.json too.
        index["coverage"] = corpus_coverage(load_corpus(out), model)
        with atomic_path(out / "index.json") as tmp:
            tmp.write_text(json.dumps(index, indent=1) + "\n")
        print("  share of frames: " + ", ".join(f"{k} {100 * v:.2f}%" for k, v in index["coverage"].items()
                                                 if k != "frames"))
    return 0
