"""touch4d: touch 4D objects through a vibrotactile glove (see README.md and docs/contracts.md)."""
import os as _os

# Nodes do many tiny linear-algebra calls; BLAS thread pools only make them crawl on a busy machine.
# Set before numpy is first imported (every node process imports touch4d first).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")
