"""refsim: an independent reference simulator of the AFM plant and the ten effects of
``shared/spec/recording.md``, the test oracle of ``visco diagnose`` (issue 13). It shares no
code with ``host-sim`` (see README.md in this directory)."""

import os as _os

# One BLAS thread: the matrices are tiny and a thread pool only adds contention.
for _v in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_v, "1")
