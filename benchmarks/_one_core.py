"""Import first in a benchmark (before numpy loads): BLAS and OpenMP pinned to one thread.

Why: the benchmarks' times are one core's, as the issues' budgets are; and worker
processes that share the two cores would each start a BLAS thread pool and oversubscribe
them (localizer_stress.py ran 16x slower with 2 workers), while the localizer's small dense
solves run slower with OpenBLAS's threads than without (the joint solver 2x on two cores).
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ[_var] = "1"
