"""identify_many: many identifications through a concurrent.futures executor.

Small GA budgets keep every job well under a second once its worker is warm;
most of the time here is process start-up (imports, numba cache loading).
"""
from __future__ import annotations

import pickle
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from identification.distributed import Job, JobResult, identify_many, seed_jobs

SMALL = dict(
    ga_options={"n_gen": 2, "n_ind": 6, "n_subpops": 2},
    refine_options={"n_starts": 1, "max_iter": 3},
)


def _jobs(path, missing):
    return [
        {"log": str(path), "seed": 11, **SMALL},
        {"log": missing, "seed": 12, **SMALL},  # fails: no such log
        Job(log=path, seed=13, options=dict(SMALL, method="paper")),
    ]


def _check(out, path):
    assert [r.index for r in out] == [0, 1, 2]
    assert [r.seed for r in out] == [11, 12, 13]
    assert all(isinstance(r, JobResult) for r in out)
    ok0, bad, ok2 = out
    assert ok0.ok and ok2.ok and not bad.ok
    assert bad.result is None
    assert bad.error_type and bad.error.startswith(bad.error_type + ":")
    assert "\n" not in bad.error
    assert "no_such_log" in bad.error
    assert ok0.result.method == "ga+pem" and ok2.result.method == "paper"
    for r in (ok0, ok2):
        assert r.result.f.shape == (9,) and np.all(np.isfinite(r.result.f))
        assert r.result.seed == r.seed
        assert "log" not in r.result  # results travel without their log
        assert r.log == str(path)
    d = ok0.to_dict()
    assert d["ok"] and d["seed"] == 11 and len(d["result"]["f"]) == 9
    assert bad.to_dict()["result"] is None


@pytest.fixture(scope="module")
def reference(paper_rigid_path):
    """The same jobs run in this process (the determinism reference)."""
    import numba

    from identification import identify

    threads = numba.get_num_threads()
    try:
        return [identify(paper_rigid_path, rng=s, workers=1, progress=False, **opts).f
                for s, opts in ((11, SMALL), (13, dict(SMALL, method="paper")))]
    finally:
        numba.set_num_threads(threads)  # workers=1 is sticky in this thread


def test_default_process_pool(paper_rigid_path, tmp_path, reference):
    out = identify_many(_jobs(paper_rigid_path, str(tmp_path / "no_such_log.csv")),
                        max_workers=2)
    _check(out, paper_rigid_path)
    # same seed, same options -> same f, whichever process ran it
    np.testing.assert_array_equal(out[0].result.f, reference[0])
    np.testing.assert_array_equal(out[2].result.f, reference[1])
    # results pickle small (no log inside)
    assert len(pickle.dumps(out[0])) < 50_000


@pytest.mark.distributed
def test_dask_local_cluster(paper_rigid_path, tmp_path, reference):
    distributed = pytest.importorskip("dask.distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cl, \
            distributed.Client(cl) as client:
        out = identify_many(_jobs(paper_rigid_path, str(tmp_path / "no_such_log.csv")),
                            executor=client.get_executor())
    _check(out, paper_rigid_path)
    np.testing.assert_array_equal(out[0].result.f, reference[0])
    np.testing.assert_array_equal(out[2].result.f, reference[1])


def test_thread_pool_and_in_memory_log(paper_log, reference):
    """Any Executor works; an ExperimentLog may be sent instead of a path."""
    with ThreadPoolExecutor(max_workers=1) as ex:
        out = identify_many(seed_jobs(paper_log, [11], **SMALL), executor=ex)
    assert out[0].ok and out[0].seed == 11 and out[0].log == paper_log.name
    np.testing.assert_array_equal(out[0].result.f, reference[0])


def test_bad_options_rejected_before_submitting(paper_rigid_path):
    class Boom:
        def submit(self, *a, **k):  # pragma: no cover - must not be reached
            raise AssertionError("submitted")

    with pytest.raises(ValueError, match="unknown identify"):
        identify_many([{"log": paper_rigid_path, "seed": 1, "n_gen": 3}], executor=Boom())
    with pytest.raises(ValueError, match="'log'"):
        identify_many([{"seed": 1}], executor=Boom())
    with pytest.raises(ValueError, match="not 'rng'"):
        identify_many([{"log": paper_rigid_path, "rng": 1}], executor=Boom())
    with pytest.raises(ValueError, match="seed"):
        identify_many([{"log": paper_rigid_path, "seed": 1.5}], executor=Boom())
    with pytest.raises(TypeError):
        identify_many([paper_rigid_path], executor=Boom())
    assert identify_many([], executor=Boom()) == []


def test_executor_failure_is_reported_per_job(paper_rigid_path):
    """A job the executor itself cannot run is reported; the others return."""

    class Flaky(ThreadPoolExecutor):
        def submit(self, fn, *args, **kwargs):
            if args[2] == 2:  # the seed
                raise RuntimeError("cannot schedule\nthis one")
            return super().submit(fn, *args, **kwargs)

    with Flaky(max_workers=1) as ex:
        out = identify_many(seed_jobs(paper_rigid_path, [1, 2], **SMALL), executor=ex)
    assert out[0].ok and not out[1].ok
    assert out[1].error == "RuntimeError: cannot schedule this one"
