"""`graphsvc build --scheduler` on a real two-worker LocalCluster: the same graph file,
byte for byte, as the local build; an unreachable scheduler is one line and exit 2."""

import numpy as np
import pytest

from graphsvc.cli import main
from graphsvc.motion.bvh import write_bvh
from tests.conftest import write_procedural_kb
from tests.motion.test_retarget import _other_skeleton


@pytest.fixture(scope="module")
def cluster():
    """Two single-threaded local workers, as `graphsvc build --workers 2` starts them."""
    from graphsvc.batch.run import local_cluster

    c = local_cluster(2)
    yield c
    c.close()


def test_cluster_build_is_the_local_build(cluster, tmp_path, capsys):
    (tmp_path / "kb").mkdir()
    kb = write_procedural_kb(tmp_path / "kb", seed=5, minutes=0.2)
    # a clip of another skeleton family: read on a worker, retargeted, prepared on a worker
    stand = _other_skeleton()
    held = stand.copy(
        rotations=np.repeat(stand.rotations, 40, axis=0), translations=np.repeat(stand.translations, 40, axis=0)
    )
    (tmp_path / "other").mkdir()
    write_bvh(tmp_path / "other" / "idle_009.bvh", held, scale=100.0)
    local, remote = tmp_path / "local.graph", tmp_path / "cluster.graph"
    assert main(["build", str(kb), str(tmp_path / "other"), "-o", str(local), "--quiet", "--jobs", "2"]) == 0
    assert (
        main(
            [
                "build",
                str(kb),
                str(tmp_path / "other"),
                "-o",
                str(remote),
                "--quiet",
                "--scheduler",
                cluster.scheduler_address,
            ]
        )
        == 0
    )
    assert "1 clips retargeted" in capsys.readouterr().out
    assert remote.read_bytes() == local.read_bytes()


def test_unreachable_scheduler_is_one_line(tmp_path, capsys):
    write_procedural_kb(tmp_path, seed=5, minutes=0.1)
    out = tmp_path / "g.graph"
    code = main(
        ["build", str(tmp_path), "-o", str(out), "--quiet", "--scheduler", "tcp://127.0.0.1:9", "--timeout", "0.5"]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "scheduler tcp://127.0.0.1:9 did not answer" in err[0]
    assert not out.exists()
