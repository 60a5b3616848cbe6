"""Search + synthesis + metrics together: noise-free input of a clip in the graph
comes back as that clip (issue 4's acceptance case)."""

import numpy as np

from graphsvc.evaluate.metrics import evaluate_frames
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.motion import signals
from graphsvc.motion.joints import canonical_indices, joint_map
from graphsvc.motion.kinematics import motion_fk
from graphsvc.motion.procedural import generate_knowledge_base
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies.options import Weights
from graphsvc.strategies.viterbi.batch import viterbi_search
from graphsvc.synthesis.path import synthesize_motion


def test_noise_free_clip_reconstructs_below_half_a_centimetre():
    kb = generate_knowledge_base(seed=4, minutes=0.7)
    graph, _ = build_graph(kb, BuildOptions(progress=False))
    for c in (0, len(kb) - 1):
        clip = kb[c]
        rec = simulate_recording(clip, PRESETS["wrists-ankles"], NOISE["none"])
        result = viterbi_search(graph, rec.accelerations, rec.ground_position, rec.heading, Weights(0.5, 1, 1))
        motion = synthesize_motion(graph, result.node_path, result.edge_path, rec.ground_position[0], rec.heading[0])
        _, true_pos = motion_fk(clip)
        _, pred_pos = motion_fk(motion)
        table = joint_map(clip.skeleton)
        canon = canonical_indices(clip.skeleton)
        out = evaluate_frames(
            pred_pos[:, canonical_indices(motion.skeleton)],
            true_pos[:, canon],
            signals.ground_position(pred_pos, joint_map(motion.skeleton)["pelvis"]),
            signals.heading(pred_pos, joint_map(motion.skeleton)),
            signals.ground_position(true_pos, table["pelvis"]),
            signals.heading(true_pos, table),
            pred_labels=[graph.labels[graph.node_label[n]] for n in result.node_path],
            true_label=clip.labels[0],
        )
        assert out["joint_err_cm"] < 0.5, (clip.name, out["joint_err_cm"])
        assert out["root_err_cm"] < 0.5 and out["heading_err_deg"] < 0.5
        assert out["label_acc"] == 1.0
        assert np.array_equal(result.node_path, graph.clips[c]["first_node"] + np.arange(rec.num_samples))
