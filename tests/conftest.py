import os

# As the CLI does (tools/__init__.py): small dense products run best on one BLAS thread.
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
