"""The boomtip command line, benchmarks, reports and visualisation.

boomtip's numerics are small dense products (3x3 solves, N x 3 scoring). Multithreaded
OpenBLAS stalls on those when the machine is busy (a 0.3 ms product measured at 31 ms), so
the command line pins BLAS to one thread unless the user says otherwise. Ray casting
(Open3D) has its own thread pool and is not affected.

OpenMP workers that spin after a parallel region (the default wait policy) steal a core
from the pipeline thread when simulation and perception alternate frame by frame (boomtip
run): the pipeline's stage times rose ~25 %. Passive waiting puts them to sleep instead.
"""

import os

for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
