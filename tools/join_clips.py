#!/usr/bin/env python3
"""Join clips end to end into one mixed-action performance, as `graphsvc evaluate
--mixed` does: each clip's ground track shifted to start where the previous one ended,
its pose and heading as recorded (the seams jump), at the graph rate.

    tools/join_clips.py CLIP... -o joined.bvh [--rate 30] [--turn]

Writes the BVH (centimetres) and, beside it, joined.labels.json: the rate and, per
clip, its name, content label, first frame and frame count — the per-frame truth
labels of the performance. --turn also turns each clip to start facing where the
previous one ended (the seams then jump in pose only). Use the BVH as the truth of
`graphsvc simulate` and `synthesize`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graphsvc.errors import GraphsvcError  # noqa: E402
from graphsvc.evaluate.mixed import join_clips  # noqa: E402
from graphsvc.fileio import write_text_atomic  # noqa: E402
from graphsvc.motion.bvh import write_bvh  # noqa: E402
from graphsvc.motion.library import load_motion  # noqa: E402
from graphsvc.motion.resample import resample  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("clips", nargs="+", type=Path)
    p.add_argument("-o", "--output", required=True, type=Path)
    p.add_argument("--rate", type=float, default=30.0)
    p.add_argument("--turn", action="store_true")
    args = p.parse_args()
    try:
        motions = [load_motion(c) for c in args.clips]
        joined, labels = join_clips(motions, args.rate, turn=args.turn, name=args.output.stem)
        write_bvh(args.output, joined, scale=100.0)
    except (GraphsvcError, OSError) as exc:
        print(f"join_clips: {exc}", file=sys.stderr)
        return 2
    clips, at = [], 0
    for m in motions:
        n = resample(m, args.rate).num_frames  # what join_clips played of it
        clips.append({"name": m.name, "label": str(labels[at]), "first_frame": at, "frames": n})
        at += n
    write_text_atomic(
        args.output.with_suffix(".labels.json"), json.dumps({"rate_hz": args.rate, "clips": clips}, indent=1) + "\n"
    )
    print(
        f"wrote {args.output} ({joined.num_frames} frames, {joined.duration_s:.1f} s) and "
        f"{args.output.with_suffix('.labels.json').name}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
