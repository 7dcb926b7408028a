"""One BLAS thread for the command line, unless the user's environment asks for more.

Our linear algebra is small and tall (N x 6 to N x 12 Jacobians): BLAS threads cost more in
start-up and hand-over than they save. On a 2-core machine a 20,000-row ``lasercal solve`` ran
1.3-3.1x slower with OpenBLAS's default of one thread per core (benchmarks/startup.py).

The limit is set through the environment because OpenBLAS (and MKL, and OpenMP runtimes)
read these variables once, when numpy or scipy first loads them; ``lasercal_hw.cli.main``
imports neither (tests/cli/test_cli_startup.py), and ``main()`` calls this first. threadpoolctl
would limit only the libraries loaded when it is called: scipy's own OpenBLAS is loaded later,
when a command imports scipy. Child processes (the dry run's fake cell) inherit the limit.
"""

from __future__ import annotations

import os

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def limit_blas_threads() -> None:
    """Set each of ``BLAS_THREAD_VARIABLES`` that the user did not set to one thread."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
