"""A node's start-up heap, out of the garbage collector's sight, so a full collection cannot stall its loop.

What a node builds before it spins (modules, config, geometry, codecs: some 60k objects) lives as
long as the process. CPython's full collection walks every tracked object; over a node's start-up
heap that takes 30-60 ms (a motor node at 1 kHz poses: one full collection mid-run, 53 ms, the
run's worst latency). Frozen (gc.freeze), those objects are skipped, and a full collection walks
only what came later. The study server freezes its own once it serves (a full collection over its
90k objects held every participant's touch for ~50 ms). Garbage made later is collected as before; a reference cycle among frozen
objects that later becomes garbage is not (a node that rebuilds its start-up structures keeps the
first ones' cycles, once).
"""
from __future__ import annotations

import gc


def freeze_startup_heap() -> int:
    """Collect what start-up left as garbage, then freeze everything alive; returns how many objects
    were frozen. Call it once, when the node is built and before it spins."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()
