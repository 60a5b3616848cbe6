#!/usr/bin/env python3
"""Mounting calibration on real motion capture: a calibration take and a match take of
one performer, simulated with one seed (so they share each sensor's mounting), the
calibration estimated from the first and applied to the second.

With the defaults: Bandai-Namco dataset 2's wave-left-hand (calibration, `--pose
stand`) and walk (reconstructed) takes 004 of the normal style, wrists-ankles sensors,
noise `default,mount=30`, seed 7, against a graph of dataset 2 without takes 004:

    graphsvc build ../shared/data/bandai/dataset-2/data --exclude '*_004.bvh' \\
        --layout wrists-ankles --jobs 2 -o d2wa.graph
    tools/probe_calibration.py d2wa.graph [--data ../shared/data/bandai/dataset-2/data]

Prints JSON: per sensor the estimated rotation's angle from the true mounting (and from
the mounting with the calibration take's own misalignment, `noise.misalign`, which the
match take does not share), its residual, the calibration's time; the match take's joint
and root error synthesized (the graph search, default options) from the mounted
recording uncalibrated, calibrated, and from the same take simulated without a
mounting; `--accelerations-only` leaves the tracker out of the match take (the search
then leans on the accelerometers alone, where a mounting shows most).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

import graphsvc  # noqa: E402,F401


def main() -> int:
    from graphsvc.errors import CalibrationQualityError
    from graphsvc.evaluate.loo import _global_signals, place_start
    from graphsvc.evaluate.metrics import joint_err_cm, root_err_cm
    from graphsvc.graph.calibration import calibrate
    from graphsvc.graph.file import load_graph
    from graphsvc.motion import quat
    from graphsvc.motion.joints import joint_map
    from graphsvc.motion.kinematics import motion_fk
    from graphsvc.motion.library import load_motion
    from graphsvc.motion.resample import resample
    from graphsvc.pipeline import reconstruct
    from graphsvc.sensors import calibration
    from graphsvc.sensors.device_model import mounting
    from graphsvc.sensors.layout import layout_from_dict
    from graphsvc.sensors.noise import corrupt_accelerations, parse_noise
    from graphsvc.sensors.simulate import simulate_recording

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("graph")
    ap.add_argument("--data", default="../shared/data/bandai/dataset-2/data")
    ap.add_argument("--calibration-take", default="dataset-2_wave-left-hand_normal_004.bvh")
    ap.add_argument("--match-take", default="dataset-2_walk_normal_004.bvh")
    ap.add_argument("--pose", default="stand")
    ap.add_argument("--noise", default="default,mount=30")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument(
        "--accelerations-only",
        action="store_true",
        help="synthesize the match take from its accelerometers alone (no tracker positions or heading)",
    )
    args = ap.parse_args()

    graph = load_graph(args.graph)
    layout = layout_from_dict(graph.layout)
    noise = parse_noise(args.noise)
    names = layout.sensor_names
    calib_motion = load_motion(Path(args.data) / args.calibration_take)
    match_motion = resample(load_motion(Path(args.data) / args.match_take), graph.rate_hz)
    take = simulate_recording(calib_motion, layout, noise, seed=args.seed)
    t0 = time.perf_counter()
    try:
        doc = calibrate(take, args.pose, graph)
    except CalibrationQualityError as exc:  # (reported under "problems" all the same)
        doc = exc.calibration
    cal = calibration.check_calibration(doc)
    calib_s = time.perf_counter() - t0
    true = mounting(args.seed, names, noise.mount)
    # The calibration take's own misalignment (drawn as simulate_recording draws it).
    _, misalign = corrupt_accelerations(np.zeros((1, len(names), 3)), noise, np.random.default_rng(args.seed), True)
    sensors = {}
    for k, n in enumerate(names):
        est = quat.to_matrix(cal["rotations"][n])
        sensors[n] = {
            "mounting_deg": round(2 * float(np.degrees(np.arccos(min(1.0, abs(true[k, 0]))))), 2),
            "error_deg": round(calibration.angle_deg(est, quat.to_matrix(true[k])), 2),
            "error_vs_mount_and_misalign_deg": round(
                calibration.angle_deg(est, quat.to_matrix(quat.mul(true[k], misalign[k]))), 2
            ),
            "residual_deg": cal["sensors"][n]["residual_deg"],
        }

    truth_table = joint_map(match_motion.skeleton)
    pred_table = joint_map(graph.skeleton, graph.params.get("mapping"))
    true_canon, true_ground, true_heading = _global_signals(motion_fk(match_motion)[1], truth_table)

    def score(rec) -> dict:
        if args.accelerations_only:
            rec = replace(rec, ground_position=None, heading=None)
        result = reconstruct(graph, rec)
        canon, ground, heading = _global_signals(motion_fk(result.motion)[1], pred_table)
        n = min(canon.shape[0], true_canon.shape[0])
        if args.accelerations_only:  # (started where the truth starts, as `graphsvc evaluate` does)
            canon, ground, heading = place_start(canon, ground, heading, true_ground[0], true_heading[0], True, True)
        _, joint = joint_err_cm(canon[:n], true_canon[:n], ground[:n], heading[:n], true_ground[:n], true_heading[:n])
        _, root = root_err_cm(ground[:n], true_ground[:n])
        return {"joint_err_cm": round(joint, 3), "root_err_cm": round(root, 2)}

    mounted = simulate_recording(match_motion, layout, noise, seed=args.seed)
    unmounted = simulate_recording(match_motion, layout, replace(noise, mount=0.0), seed=args.seed)
    out = {
        "graph": str(args.graph),
        "calibration_take": args.calibration_take,
        "match_take": args.match_take,
        "pose": args.pose,
        "noise": args.noise,
        "seed": args.seed,
        "match_inputs": "accelerations" if args.accelerations_only else "accelerations, tracker positions and heading",
        "rest_s": cal["rest_s"],
        "matched_samples": cal["matched_samples"],
        "problems": cal["problems"],
        "calibrate_s": round(calib_s, 3),
        "sensors": sensors,
        "match": {
            "without_mounting": score(unmounted),
            "mounted_calibrated": score(calibration.apply_calibration(mounted, cal)),
            "mounted_uncalibrated": score(mounted),
        },
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
