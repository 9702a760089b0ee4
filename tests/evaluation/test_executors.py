"""evaluate_dataset on any concurrent.futures.Executor: threads, and a Dask cluster."""

from __future__ import annotations

import functools
import importlib.util
import shutil
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from srde_fusion.cli import main
from srde_fusion.cli.backbones import backbone_from
from srde_fusion.errors import SRDEError
from srde_fusion.evaluation import BackboneLoader, evaluate_dataset

# How many times _counted_flat made a backbone, per token (one test, one token).
LOADS: dict[str, int] = {}


def flat(left, right):
    return np.full(left.shape[:2], 15.0, np.float32)


def _counted_flat(token: str):
    LOADS[token] = LOADS.get(token, 0) + 1
    return flat


def scores_only(evaluation) -> dict:
    data = evaluation.to_dict()
    del data["run"]
    for scene in data["scenes"]:
        del scene["seconds"]
    return data


def test_a_thread_pool_gives_the_serial_scores(dataset):
    serial = evaluate_dataset(dataset, flat, progress=False)
    with ThreadPoolExecutor(2) as pool:
        threaded = evaluate_dataset(dataset, flat, progress=False, executor=pool)
    assert [s.name for s in threaded.scenes] == [s.name for s in serial.scenes]
    assert scores_only(threaded) == scores_only(serial)
    assert threaded.runner == "ThreadPoolExecutor" and threaded.jobs == 1  # one process
    assert threaded.to_dict()["run"]["runner"] == "ThreadPoolExecutor"
    assert serial.runner == "this process"


def test_a_loader_is_loaded_once_per_process(dataset, tmp_path):
    loader = BackboneLoader(functools.partial(_counted_flat, str(tmp_path)))
    with ThreadPoolExecutor(2) as pool:
        evaluation = evaluate_dataset(dataset, loader, progress=False, executor=pool)
        assert len(evaluation.scenes) == 2
        evaluate_dataset(dataset, loader, progress=False, executor=pool)
    assert LOADS[str(tmp_path)] == 1


def test_failures_and_strict_on_an_executor(dataset, tmp_path):
    data = tmp_path / "data"
    shutil.copytree(dataset, data)
    (data / "scene_0000" / "rig.json").write_text("{")
    with ThreadPoolExecutor(2) as pool:
        evaluation = evaluate_dataset(data, flat, progress=False, executor=pool)
        assert [s.name for s in evaluation.scenes] == ["scene_0001"]
        assert [(f.name, f.error) for f in evaluation.failures] == [("scene_0000", "RigError")]
        with pytest.raises(SRDEError, match="rig.json: expected valid JSON"):
            evaluate_dataset(data, flat, progress=False, executor=pool, strict=True)


def test_executor_errors(dataset):
    with pytest.raises(SRDEError, match="executor: expected a concurrent.futures.Executor, "
                                        "got str"):
        evaluate_dataset(dataset, flat, executor="tcp://scheduler:8786")
    with ThreadPoolExecutor(1) as pool, pytest.raises(
            SRDEError, match="jobs, executor: expected one way to run the scenes in parallel, "
                             "got jobs=2 and an executor"):
        evaluate_dataset(dataset, flat, executor=pool, jobs=2)


def test_a_backbone_that_cannot_load_is_raised_not_recorded(dataset):
    def broken():
        raise SRDEError("model.onnx: expected an ONNX model, got garbage")

    with ThreadPoolExecutor(2) as pool, pytest.raises(SRDEError, match="got garbage"):
        evaluate_dataset(dataset, BackboneLoader(broken), progress=False, executor=pool)


def test_eval_scheduler_option_errors(dataset, capsys):
    code = main(["eval", str(dataset), "--backbone", "default", "--scheduler", "nonsense://x"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    if importlib.util.find_spec("distributed") is None:  # the [cluster] extra is optional
        assert ("--scheduler: expected Dask's distributed package (pip install "
                "'srde-fusion[cluster]'), got none installed") in err[0]
    else:
        assert ("--scheduler: expected a Dask scheduler at 'nonsense://x', got ValueError"
                in err[0])
    code = main(["eval", str(dataset), "--backbone", "default", "--scheduler", "tcp://h:1",
                 "--jobs", "2"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and "--jobs, --scheduler: expected one of them" in err[0]


@pytest.mark.slow
def test_a_local_dask_cluster_gives_the_one_process_scores(dataset, tmp_path, capsys):
    distributed = pytest.importorskip("distributed")
    import json

    loader = BackboneLoader(functools.partial(backbone_from, "default", None, threads=1))
    serial = evaluate_dataset(dataset, loader, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False,
                                  dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            clustered = evaluate_dataset(dataset, loader, progress=False,
                                         executor=client.get_executor())
        assert clustered.runner == "ClientExecutor"
        assert scores_only(clustered) == scores_only(serial)
        # the command line, on the same cluster by its address
        code = main(["eval", str(dataset), "--backbone", "default", "--scheduler",
                     cluster.scheduler_address, "--quiet", "--out", str(tmp_path / "e")])
        out = capsys.readouterr().out
    assert code == 0
    assert f"of the Dask cluster at {cluster.scheduler_address}" in out
    data = json.loads((tmp_path / "e" / "eval.json").read_text())
    assert data["settings"]["scheduler"] == cluster.scheduler_address
    assert data["summary"] == serial.to_dict()["summary"]
