"""numba compilation on first use (`lazy_njit`): the geometry every node imports keeps numba (about
0.2 s and tens of MB to import) out of the processes that never call a compiled function, such as a
served participant's nodes. Compiled code that calls one (the physics step) takes its `.compiled`."""
from __future__ import annotations

import functools
import types


class LazyNjit:
    """A function compiled by `numba.njit(**options)` the first time it is called (or `.compiled` is
    read); the LazyNjit functions it calls are compiled with it."""

    def __init__(self, func, options: dict):
        self.func, self.options, self._compiled = func, options, None
        functools.update_wrapper(self, func)

    @property
    def compiled(self):
        if self._compiled is None:
            from numba import njit

            scope = dict(self.func.__globals__)
            for name in self.func.__code__.co_names:
                if isinstance(scope.get(name), LazyNjit):
                    scope[name] = scope[name].compiled
            f = types.FunctionType(self.func.__code__, scope, self.func.__name__, self.func.__defaults__,
                                   self.func.__closure__)
            f.__qualname__, f.__module__, f.__doc__ = self.func.__qualname__, self.func.__module__, self.func.__doc__
            self._compiled = njit(**self.options)(f)
        return self._compiled

    def __call__(self, *args):
        return self.compiled(*args)


def lazy_njit(**options):
    """`@lazy_njit(cache=True, nogil=True)`: as numba's `@njit(...)`, compiled on first use."""
    return lambda func: LazyNjit(func, options)
