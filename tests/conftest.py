"""Test set-up shared by every test module."""
import touch4d  # noqa: F401  first: it caps BLAS thread pools (tiny matrices, busy 2-core machines)
