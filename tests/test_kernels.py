"""CPU kernels pinned for the jobs (`ambid.kernels`): the same bytes on every x86-64 machine."""

import os
import subprocess
import sys

import pytest

from ambid import kernels
from ambid.kernels import JOB_THREADS, PINNED_KERNELS, pin_cpu_kernels, pin_job_threads


def test_the_kernels_are_pinned_and_the_users_choice_kept(monkeypatch):
    monkeypatch.setattr(kernels.platform, "machine", lambda: "x86_64")
    monkeypatch.setattr(kernels, "_has_avx2", lambda: True)
    environ = {"OPENBLAS_CORETYPE": "SkylakeX"}
    assert pin_cpu_kernels(environ) == {"NPY_DISABLE_CPU_FEATURES": PINNED_KERNELS["NPY_DISABLE_CPU_FEATURES"]}
    assert environ["OPENBLAS_CORETYPE"] == "SkylakeX"


def test_each_job_gets_one_blas_thread_on_every_platform_and_the_users_choice_is_kept(monkeypatch):
    monkeypatch.setattr(kernels.platform, "machine", lambda: "aarch64")
    environ = {"OMP_NUM_THREADS": "4"}
    assert pin_job_threads(environ) == {"OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
    assert environ["OMP_NUM_THREADS"] == "4" and set(environ) == set(JOB_THREADS)


@pytest.mark.parametrize("machine, avx2", [("aarch64", True), ("x86_64", False)])
def test_nothing_is_pinned_where_avx2_kernels_cannot_run(monkeypatch, machine, avx2):
    monkeypatch.setattr(kernels.platform, "machine", lambda: machine)
    monkeypatch.setattr(kernels, "_has_avx2", lambda: avx2)
    environ = {}
    assert pin_cpu_kernels(environ) == {} and environ == {}


def test_a_process_started_with_them_runs_numpy_without_avx512():
    environ = {key: value for key, value in os.environ.items() if key not in PINNED_KERNELS}
    if not pin_cpu_kernels(environ):
        pytest.skip("not an x86-64 CPU with AVX2")
    probe = ("from numpy._core._multiarray_umath import __cpu_features__ as f; "
             "print(int(any(f.get(k) for k in ('X86_V4', 'AVX512_ICL', 'AVX512_SPR'))))")
    result = subprocess.run([sys.executable, "-c", probe], env=environ, capture_output=True, text=True, check=True)
    assert result.stdout.strip() == "0"


def test_a_benchmark_runs_itself_again_pinned_once(monkeypatch):
    """`rerun_pinned` re-executes the script with the same arguments when it pinned something, and returns when the
    kernels were pinned already (the re-executed process), so it never loops."""
    monkeypatch.setattr(kernels.platform, "machine", lambda: "x86_64")
    monkeypatch.setattr(kernels, "_has_avx2", lambda: True)
    started = []
    monkeypatch.setattr(kernels.os, "execv", lambda path, argv: started.append((path, argv)))
    monkeypatch.setattr(kernels.sys, "argv", ["benchmarks/bench_diagnose.py", "2", "--suite"])
    for name in PINNED_KERNELS:  # set then deleted, so that the test leaves the environment as it found it
        monkeypatch.setenv(name, "")
        monkeypatch.delenv(name)
    kernels.rerun_pinned()
    assert started == [(sys.executable, [sys.executable, "benchmarks/bench_diagnose.py", "2", "--suite"])]
    assert all(os.environ[name] == value for name, value in PINNED_KERNELS.items())
    kernels.rerun_pinned()  # as the re-executed process: nothing left to pin
    assert len(started) == 1
