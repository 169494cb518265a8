"""`python -m worker`: a Celery worker process with fringelab's tasks."""

import os
import sys

# The numerical libraries' thread pools, one thread each, set before numpy is loaded (BLAS reads them once): the
# worker's processes are its parallelism, one per core, and a pool per process on top would put more threads than
# cores on the machine. A value set in the environment is kept.
for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

from worker.app import main  # noqa: E402

sys.exit(main())
