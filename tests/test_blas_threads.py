"""One BLAS thread while box_core's leave-one-out runs, in this process and in the second
process it starts (``pipeline.planning.blas.single_thread_with_children``)."""

import os
import subprocess
import sys

from threadpoolctl import threadpool_info

from pipeline.planning.blas import THREAD_VARIABLES, single_thread_with_children


def _blas_threads() -> set[int]:
    return {i["num_threads"] for i in threadpool_info() if i.get("user_api") == "blas"}


def test_one_thread_here_and_in_a_process_started_meanwhile(monkeypatch):
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    monkeypatch.delenv("MKL_NUM_THREADS", raising=False)
    before = _blas_threads()
    probe = ("from threadpoolctl import threadpool_info; print(max(i['num_threads'] for i in "
             "threadpool_info() if i.get('user_api') == 'blas'))")
    with single_thread_with_children():
        assert _blas_threads() == {1}
        child = subprocess.run([sys.executable, "-c", "import numpy; " + probe],
                               capture_output=True, text=True, check=True)
        assert child.stdout.strip() == "1"
        assert all(os.environ[name] == "1" for name in THREAD_VARIABLES)
    assert _blas_threads() == before  # restored, as is the environment
    assert os.environ["OPENBLAS_NUM_THREADS"] == "2" and "MKL_NUM_THREADS" not in os.environ
