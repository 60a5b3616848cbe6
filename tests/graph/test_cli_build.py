"""`graphsvc build` and `graphsvc info` end to end, bad input included."""

import json

import pytest

from graphsvc.cli import main
from tests.conftest import write_procedural_kb


@pytest.fixture(scope="module")
def kb_dir(tmp_path_factory):
    return write_procedural_kb(tmp_path_factory.mktemp("kb"), seed=5, minutes=0.8)


def test_build_then_info(kb_dir, tmp_path, capsys):
    out = tmp_path / "kb.graph"
    assert main(["build", str(kb_dir), "-o", str(out), "--layout", "kelly6", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "transition" in printed and "times:" in printed
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["layout"] == "kelly6" and info["nodes"] > info["kb_frames"] > 0
    assert info["file_bytes"] == out.stat().st_size
    assert set(info["labels"]) <= {"walk", "run", "stop", "idle", "forehand", "backhand", "overhead", "punch"}
    assert "largest strongly connected component" in printed and "reach from a typical node" in printed
    conn = info["connectivity"]
    assert conn["nodes"] == info["nodes"] and 0 < conn["largest_share"] <= 1
    assert set(conn["reach"]) == set(info["labels"])
    assert info["bridges"] > 0 and info["nodes_by_kind"]["bridge"] > 0
    assert main(["info", str(out)]) == 0
    assert "reach from a typical node" in capsys.readouterr().out


def test_no_bridges(kb_dir, tmp_path, capsys):
    out = tmp_path / "plain.graph"
    assert main(["build", str(kb_dir), "--no-bridges", "-o", str(out), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["bridges"] == 0 and info["nodes_by_kind"]["bridge"] == 0 and info["params"]["bridges"] is False


def test_exclude_and_no_msv(kb_dir, tmp_path, capsys):
    out = tmp_path / "small.graph"
    assert main(["build", str(kb_dir), "--exclude", "run_*", "--no-msv", "-o", str(out), "--quiet"]) == 0
    capsys.readouterr()
    main(["info", str(out), "--json"])
    info = json.loads(capsys.readouterr().out)
    assert "run" not in info["labels"] and info["nodes_by_kind"]["slow-down"] == 0


@pytest.mark.parametrize(
    "case, needle",
    [
        ("empty", "empty"),
        ("missing-folder", "does not exist"),
        ("layout", "unknown layout"),
        ("short", "shorter than the distance window"),
        ("corrupt-info", "corrupted"),
    ],
)
def test_bad_input_exit_2_no_file(kb_dir, tmp_path, capsys, case, needle):
    empty = tmp_path / "empty"
    empty.mkdir()
    out = tmp_path / "g.graph"
    argv = ["build", str(kb_dir), "-o", str(out), "--quiet"]
    if case == "empty":
        argv[1] = str(empty)
    elif case == "missing-folder":
        argv[3] = str(tmp_path / "nope" / "g.graph")
    elif case == "layout":
        argv += ["--layout", "elbows"]
    elif case == "short":
        text = sorted(kb_dir.glob("*.bvh"))[0].read_text()
        head, frames = text.split("MOTION\n")
        lines = frames.splitlines()
        short = head + "MOTION\nFrames: 3\n" + lines[1] + "\n" + "\n".join(lines[2:5]) + "\n"
        (empty / "tiny.bvh").write_text(short)
        argv = ["build", str(kb_dir), str(empty / "tiny.bvh"), "-o", str(out), "--quiet"]
    elif case == "corrupt-info":
        assert main(argv) == 0
        capsys.readouterr()
        data = bytearray(out.read_bytes())
        data[len(data) // 2] ^= 1
        out.write_bytes(data)
        argv = ["info", str(out)]
    code = main(argv)
    err = capsys.readouterr().err
    assert code == 2 and needle in err and len(err.strip().splitlines()) == 1
    if case != "corrupt-info":
        assert not out.exists() and not list(tmp_path.glob(".g.graph*"))


def test_relayout_changes_only_the_sensor_metadata(kb_dir, tmp_path, capsys):
    from graphsvc.graph.file import load_graph

    src, out = tmp_path / "a.graph", tmp_path / "b.graph"
    assert main(["build", str(kb_dir), "-o", str(src), "--quiet", "--no-interp"]) == 0
    assert main(["relayout", str(src), "--layout", "right-wrist", "-o", str(out)]) == 0
    capsys.readouterr()
    a, b = load_graph(src), load_graph(out)
    assert b.sensor_names == ("r_wrist",) and b.edge_acc.shape == (a.num_edges, 1, 3)
    assert b.params["layout"] == "right-wrist"
    for name in ("edge_src", "edge_dst", "edge_offset", "node_rot64", "node_moving", "node_bones", "bone_sets"):
        assert (getattr(a, name) == getattr(b, name)).all()


def test_unknown_skeleton_needs_a_mapping(kb_dir, tmp_path, capsys):
    # Rename the procedural joints: no built-in map fits any more.
    renamed = tmp_path / "renamed"
    renamed.mkdir()
    names = ["pelvis", "spine", "chest", "l_wrist", "r_wrist", "l_ankle", "r_ankle"]
    for f in sorted(kb_dir.glob("*.bvh"))[:4]:
        text = f.read_text()
        for n in names:
            text = text.replace(f"JOINT {n}\n", f"JOINT X{n}\n").replace(f"ROOT {n}\n", f"ROOT X{n}\n")
        (renamed / f.name).write_text(text)
    out = tmp_path / "g.graph"
    assert main(["build", str(renamed), "-o", str(out), "--quiet", "--no-interp"]) == 2
    assert "mapping" in capsys.readouterr().err and not out.exists()
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps({n: f"X{n}" for n in names}))
    assert main(["build", str(renamed), "-o", str(out), "--quiet", "--no-interp", "--mapping", str(mapping)]) == 0
    out2 = tmp_path / "g2.graph"
    assert main(["relayout", str(out), "--layout", "kelly6", "-o", str(out2)]) == 0
