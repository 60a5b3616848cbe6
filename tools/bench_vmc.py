#!/usr/bin/env python3
"""Cost of the VMC output (`--vmc`): one pose frame turned into its OSC bundle and sent
over UDP to a loopback port nobody reads, per frame, with the frames of a BVH clip (or
the procedural performance) on its skeleton.

    .venv/bin/python tools/bench_vmc.py [--clip CLIP.bvh] [--frames 3000]

Prints one JSON object: skeleton joints, bones sent, bundle bytes, µs a frame to build
the bundle (forward kinematics, the bones' local rotations, OSC encoding) and to build
and send it, and the share of one core a 30 Hz stream's output takes.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--clip", metavar="CLIP.bvh", help="a BVH clip (default: the procedural performance)")
    parser.add_argument("--frames", type=int, default=3000, help="frames to send (default 3000)")
    args = parser.parse_args(argv)

    from graphsvc.service.vmc import VmcSender

    if args.clip:
        from graphsvc.motion.bvh import read_bvh

        motion = read_bvh(args.clip)
    else:
        from graphsvc.motion.procedural import generate_performance

        motion = generate_performance(seed=1)[0]
    skeleton, rotations, translations = motion.skeleton, motion.rotations, motion.translations
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sink:  # (bound, never read: the kernel drops)
        sink.bind(("127.0.0.1", 0))
        sender = VmcSender(f"127.0.0.1:{sink.getsockname()[1]}", skeleton)
        n = min(args.frames, len(rotations))
        frames = [(rotations[k], translations[k], k / 30.0) for k in range(n)]
        start = time.perf_counter()
        bundles = [sender.bundle(*f) for f in frames]
        build_s = time.perf_counter() - start
        start = time.perf_counter()
        for f in frames:
            sender.socket.sendto(sender.bundle(*f), sender.target)
        send_s = time.perf_counter() - start
    print(
        json.dumps(
            {
                "joints": skeleton.num_joints,
                "bones": len(sender.rig.names),
                "frames": n,
                "bundle_bytes": len(bundles[0]),
                "build_us_per_frame": round(1e6 * build_s / n, 1),
                "build_and_send_us_per_frame": round(1e6 * send_s / n, 1),
                "core_share_at_30_hz": round(30 * send_s / n, 4),
            }
        )
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
