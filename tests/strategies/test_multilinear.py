"""The multilinear strategy (graphsvc/strategies/multilinear/): the HOSVD keeps the
stated variance and gives back its rows; the fit finds the mixing coefficients of a
known mix; hidden clips never enter a tensor; a held-out take reconstructs; bad input
and live streams are refused with one line."""

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.errors import InputError
from graphsvc.evaluate.metrics import truth_errors
from graphsvc.evaluate.protocols import PROTOCOLS, hide_lists
from graphsvc.graph.build import BuildOptions, build_graph
from graphsvc.graph.file import save_graph
from graphsvc.graph.holdout import held_out_mask
from graphsvc.motion.procedural import make_clip
from graphsvc.motion.procedural.body import standard_skeleton
from graphsvc.pipeline import Options, open_session, reconstruct
from graphsvc.sensors.layout import PRESETS
from graphsvc.sensors.noise import PRESETS as NOISE
from graphsvc.sensors.recording import save_recording
from graphsvc.sensors.simulate import simulate_recording
from graphsvc.strategies import get
from graphsvc.strategies.base import prepared_index
from graphsvc.strategies.multilinear import MultilinearOptions
from graphsvc.strategies.multilinear import tensor as tn
from graphsvc.strategies.multilinear.fit import fit_unit, graph_body, simulate_unit
from graphsvc.strategies.multilinear.model import decompose, frame_data, gather_units, tensor_of, unit_values
from graphsvc.strategies.multilinear.strategy import learned_model

LAYOUT = PRESETS["wrists-ankles"]


def _clips(seed=3, seconds=3.0):
    """Walks and punches in two styles, three takes each, and one take of standing."""
    rng = np.random.default_rng(seed)
    sk = standard_skeleton()
    clips = [
        make_clip(kind, rng, sk, 30.0, seconds, f"{kind}_{style}_{take:03d}", seed)
        for kind in ("walk", "punch")
        for style in ("a", "b")
        for take in (1, 2, 3)
    ]
    return clips + [make_clip("idle", rng, sk, 30.0, 3.0, "idle_a_001", seed)]


@pytest.fixture(scope="module")
def kb():
    clips = _clips()
    return [c for c in clips if c.name != "walk_a_003"], clips[2]  # (the knowledge base, a held-out take)


@pytest.fixture(scope="module")
def graph(kb):
    g, _ = build_graph(kb[0], BuildOptions(layout=LAYOUT, progress=False))
    return g


def _unfold(X, mode):
    return np.moveaxis(X, mode, 0).reshape(X.shape[mode], -1)


def test_hosvd_keeps_the_stated_variance_and_gives_back_its_rows():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(7, 5, 4, 6)) * np.array([3.0, 1.0, 0.5, 0.2, 0.1, 0.05])[None, None, None, :]
    for share in (0.5, 0.8, 0.95, 1.0):
        t = decompose(X, share)
        centred = X - X.mean(axis=(2, 3), keepdims=True)
        for mode, k in ((2, 0), (3, 1)):
            s = np.linalg.svd(_unfold(centred, mode), compute_uv=False)
            energy = np.cumsum(s**2) / np.sum(s**2)
            kept = int(t["kept"][k])
            assert energy[kept - 1] >= share - 1e-12 and (kept == 1 or energy[kept - 2] < share), (share, mode)
            np.testing.assert_allclose(t["sv_style" if mode == 2 else "sv_rep"], s, rtol=0, atol=1e-9 * s[0])
    # every row back from its own rows of the untruncated matrices, up to float error
    full = tensor_of(
        {
            **decompose(X, 1.0),
            "row_clip": np.zeros(24),
            "row_frame": np.zeros((24, 5)),
            "row_readings": np.zeros((24, 5, 3)),
        }
    )
    core = tn.natural_core(X - full.mean[:, :, None, None], full.u_style, full.u_rep)
    for s in range(4):
        for r in range(6):
            got = full.mean + tn.synthesize(core, full.u_style[s], full.u_rep[r])
            np.testing.assert_allclose(got, X[:, :, s, r], atol=1e-12)


def test_the_fit_gives_back_the_mixing_coefficients_of_a_new_mix(graph):
    """Takes that are known mixes α·A + (1 − α)·B of two steps; the noise-free readings
    of a new mix (α = 0.3) are fitted, and the fitted row weights mix α back."""
    data = frame_data(graph)
    groups, _ = gather_units(graph, data, np.arange(len(graph.clips)))
    steps = next(g for g in groups if g.foot == 0).units
    (ca, a0, a1), (cb, b0, b1) = steps["a"][1], steps["b"][2]
    d = int(data["pose_dims"][0])
    F = 16
    A = tn.sample(unit_values(data, ca, a0, a1), np.linspace(0, a1 - a0 - 1, F))
    B = tn.sample(unit_values(data, cb, b0, b1), np.linspace(0, b1 - b0 - 1, F))
    alpha = np.array([[0.0, 0.2, 0.5], [0.7, 0.9, 1.0]])
    X = np.stack([[(al * A + (1 - al) * B).T for al in row] for row in alpha])  # (S, R, V, F)
    X = np.moveaxis(X, (0, 1), (2, 3))
    body = graph_body(graph)
    readings = np.stack([simulate_unit(X[:, :, s, r].T, body).reshape(F, -1) for s in range(2) for r in range(3)])
    t = tensor_of(
        {
            **decompose(X, 1.0),
            "row_clip": np.zeros(6, np.int64),
            "row_frame": np.zeros((6, F)),
            "row_readings": readings,
        }
    )
    target = 0.3 * A + 0.7 * B
    measured = simulate_unit(target, body)
    fit = fit_unit(t, measured, np.ones(F, bool), body, prior=0.0, warp=False, evaluations=200)
    w = t.row_weights(fit.x_s, fit.x_r)
    assert fit.cost < 1e-8
    assert abs(w.sum() - 1.0) < 1e-3 and abs(w @ alpha.reshape(-1) - 0.3) < 1e-3, (w, fit)
    assert d > 0


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_hidden_clips_never_enter_a_tensor(graph, kb, protocol):
    strategy = get("multilinear")
    test = kb[0][0]  # walk_a_001
    hide = hide_lists(graph, [test], protocol)[0]
    arrays = learned_model(graph, prepared_index(strategy, graph), MultilinearOptions(), held_out_mask(graph, hide))
    used = set(np.asarray(arrays["clips"]).tolist())
    rows = set(np.concatenate([np.asarray(v) for k, v in arrays.items() if k.endswith(".row_clip")]).tolist())
    assert hide and not (used | rows) & set(hide)
    assert rows <= used
    everything = learned_model(graph, prepared_index(strategy, graph), MultilinearOptions())
    assert set(hide) & set(np.concatenate([np.asarray(v) for k, v in everything.items() if k.endswith(".row_clip")]))


def test_a_held_out_take_is_reconstructed(graph, kb):
    truth = kb[1]
    rec = simulate_recording(truth, LAYOUT, NOISE["none"], seed=0, rate_hz=graph.rate_hz)
    r = reconstruct(graph, rec, Options(strategy="multilinear"))
    units = r.report["multilinear"]["units"]
    assert units and all(u["class"] == "walk" and u["cost"] <= u["start_cost"] + 1e-12 for u in units)
    assert {u["foot"] for u in units} == {"left", "right"}
    e = truth_errors(r.motion, truth)
    assert e["joint_err_cm"] < 3.0 and r.motion.num_frames == rec.num_samples
    assert r.provenance.weight.sum(axis=1) == pytest.approx(1.0)
    held = reconstruct(
        graph, rec, Options(strategy="multilinear", settings={"multilinear": MultilinearOptions(hold_feet=True)})
    )
    assert np.abs(held.motion.rotations - r.motion.rotations).max() > 1e-6  # (the legs turned to hold the feet)
    np.testing.assert_array_equal(held.motion.translations, r.motion.translations)


def test_its_report_becomes_a_page(graph, kb, tmp_path):
    from graphsvc.pipeline import synthesize_files
    from graphsvc.report.html import write_html
    from graphsvc.report.load import load_document

    g, r = tmp_path / "g.graph", tmp_path / "r.rec"
    save_graph(graph, g)
    save_recording(simulate_recording(kb[1], LAYOUT, NOISE["none"], seed=0, rate_hz=graph.rate_hz), r)
    synthesize_files(graph, g, r, tmp_path / "o.bvh", Options(strategy="multilinear"), report_path=tmp_path / "o.json")
    (view,) = load_document(tmp_path / "o.json")["clips"]
    segments = view["timeline"]["segments"]
    assert sum(s["frames"] for s in segments) == view["frames"] and {s["clip"] for s in segments} <= {
        c["name"] for c in graph.clips
    }
    write_html(tmp_path / "page.html", load_document(tmp_path / "o.json"))
    assert (tmp_path / "page.html").read_text().startswith("<!DOCTYPE html>")


def test_bad_input_gives_one_line_and_exit_2(graph, kb, tmp_path, capsys):
    g, r, short = tmp_path / "g.graph", tmp_path / "r.rec", tmp_path / "s.rec"
    save_graph(graph, g)
    rec = simulate_recording(kb[1], LAYOUT, NOISE["none"], seed=0, rate_hz=graph.rate_hz)
    save_recording(rec, r)
    save_recording(simulate_recording(kb[1].slice(0, 8), LAYOUT, NOISE["none"], seed=0, rate_hz=graph.rate_hz), short)
    for args, message in (
        ([str(r), "--multilinear-label", "idle"], "fewer than two takes"),
        ([str(r), "--multilinear-label", "swim"], "not a class"),
        ([str(short)], "shorter than one motion unit"),
        ([str(r), "--multilinear-variance", "0"], "variance"),
    ):
        capsys.readouterr()
        try:
            code = main(["synthesize", str(g), *args, "--strategy", "multilinear", "-o", str(tmp_path / "o.bvh")])
        except SystemExit as e:
            code = e.code
        err = capsys.readouterr().err
        assert code == 2 and message in err and err.count("\n") == 1, err
    with pytest.raises(InputError, match="live streams are refused"):
        open_session(graph, Options(strategy="multilinear"), rec.sensor_names)


def test_a_knowledge_base_without_takes_is_refused():
    rng = np.random.default_rng(1)
    sk = standard_skeleton()
    clips = [make_clip("walk", rng, sk, 30.0, 3.0, f"walk_{k:02d}", 1) for k in range(2)]
    g, _ = build_graph(clips, BuildOptions(layout=LAYOUT, progress=False))
    rec = simulate_recording(clips[0], LAYOUT, NOISE["none"], seed=0, rate_hz=g.rate_hz)
    with pytest.raises(InputError, match="no class of the knowledge base has two takes"):
        reconstruct(g, rec, Options(strategy="multilinear"))
