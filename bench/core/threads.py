"""How many threads the numerical libraries may use while a calibration runs: one.

A calibration's linear algebra is many small problems (normal equations of ~100 parameters, 4,000-row
regressors): a second BLAS thread barely shortens one of them, and on a loaded machine the BLAS
threads spin against the other work (measured on 2 cores at load 3: 176 s of CPU for 167 s of wall
before this limit, docs/calibration.md). `one_blas_thread()` limits numpy's and scipy's BLAS to one
thread for its duration; MuJoCo's rollouts keep the `threads=` their command was given (default 1).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def one_blas_thread() -> Iterator[None]:
    """numpy's and scipy's BLAS limited to one thread inside the block (both loaded first, so both are limited)."""
    import scipy.linalg  # noqa: F401  scipy: loaded here so that its own BLAS is there to be limited
    from threadpoolctl import threadpool_limits  # threadpoolctl: loaded only by work that limits its threads

    with threadpool_limits(limits=1, user_api="blas"):
        yield
