"""The Ray path: one experiment's fast mode (a training run and the evaluation that reads its
checkpoint) dispatched as tasks to a local Ray instance of one CPU; the results file as the
in-process run writes it."""

import pytest

from tools import experiments

ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'swarmctl[cluster]')")

pytestmark = pytest.mark.slow  # about 25 s: Ray's start-up and one worker


@pytest.fixture(scope="module")
def local_ray():
    # address="local": a new instance even where another cluster's address is on record (/tmp/ray)
    ray.init(address="local", num_cpus=1, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def test_fast_mode_through_ray_matches_the_local_run(local_ray, tmp_path):
    argv = ["obstacles", "--fast", "--set", "train_uavs=[2]"]
    through_ray = experiments.main([*argv, "--ray", "auto", "--out", str(tmp_path / "ray")])["obstacles"]
    assert through_ray["runs_done"] == through_ray["runs_total"] == 2
    assert (tmp_path / "ray" / "runs" / "train-u2.pt").exists()  # the checkpoint came back from the worker
    assert (tmp_path / "ray" / "obstacles.png").exists()
    local = experiments.main([*argv, "--out", str(tmp_path / "local")])["obstacles"]
    strip = lambda rec: [{k: v for k, v in r.items() if k != "decision_ms_per_vehicle"} for r in rec["results"]]
    assert strip(through_ray["runs"]["eval-test-u3"]) == strip(local["runs"]["eval-test-u3"])  # same seed, same result
