"""The same numbers on every x86-64 machine: numpy's and OpenBLAS' CPU kernels pinned to AVX2.

numpy (its SIMD loops) and OpenBLAS (``DYNAMIC_ARCH``) choose their kernels by
the CPU they run on, and AVX-512 kernels round differently from AVX2 ones.  The
virtual rig's stepped sine adapts each step's amplitude to the response it
measures, so a last-bit difference can change a decision and the log with it:
the default workflow's hs_eden_like ledger read 3085 instead of 3167 chi2 per
point for the variant ``amplifier`` on an AVX-512 machine.  Pinned to the AVX2
kernels (which every x86-64 CPU since 2013 has), a run gives the same bytes on
any of them.  The Snakefile pins the jobs it starts, and the benchmarks that
drive the rig run themselves again pinned (`rerun_pinned`); a value the user
set already is kept.
"""

import os
import platform
import sys

__all__ = ["PINNED_KERNELS", "JOB_THREADS", "pin_cpu_kernels", "pin_job_threads", "rerun_pinned"]

#: numpy's dispatch targets beyond AVX2 (numpy 2.x group names) and OpenBLAS' AVX2 kernel family.
PINNED_KERNELS = {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR", "OPENBLAS_CORETYPE": "Haswell"}


#: One BLAS and OpenMP thread per job, as every rule declares (``threads: 1``): left to themselves OpenBLAS and OpenMP
#: start a thread per core in each of the jobs Snakemake runs side by side.  (The default run with one thread per job
#: is byte for byte the run without it, stop 55.)
JOB_THREADS = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def _has_avx2():
    try:
        from numpy._core._multiarray_umath import __cpu_features__
    except ImportError:  # another numpy layout: leave the kernels as they are
        return False
    return bool(__cpu_features__.get("AVX2") and __cpu_features__.get("FMA3"))


def pin_cpu_kernels(environ=None):
    """Pin the kernels of the processes started from ``environ`` (default ``os.environ``) to AVX2.

    Only on x86-64 CPUs with AVX2 and FMA (elsewhere nothing is set: forcing
    AVX2 kernels on a CPU without them would stop the process); variables
    already set are kept.  A process reads them when it imports numpy, so the
    one that calls this is not changed, only those it starts.

    Returns
    -------
    dict
        The variables set.
    """
    environ = os.environ if environ is None else environ
    if platform.machine().lower() not in ("x86_64", "amd64") or not _has_avx2():
        return {}
    added = {name: value for name, value in PINNED_KERNELS.items() if name not in environ}
    environ.update(added)
    return added


def pin_job_threads(environ=None):
    """One BLAS and OpenMP thread for the processes started from ``environ`` (default ``os.environ``): `JOB_THREADS`.

    On every platform; variables already set are kept.

    Returns
    -------
    dict
        The variables set.
    """
    environ = os.environ if environ is None else environ
    added = {name: value for name, value in JOB_THREADS.items() if name not in environ}
    environ.update(added)
    return added


def rerun_pinned():
    """Start the running script again with its kernels pinned (`pin_cpu_kernels`), unless they are already.

    For the benchmarks that drive the rig: their figures (what the diagnosis
    names on a rig's log) then do not depend on the CPU they ran on.  Returns
    only when nothing needed pinning.
    """
    if pin_cpu_kernels():
        sys.stdout.flush()
        os.execv(sys.executable, [sys.executable, *sys.argv])
