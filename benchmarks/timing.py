"""The benchmarks' timers: the best of a few runs, so a busy shared machine distorts them least."""

import time


def best_of_each(fns, repeats=5, clock=time.perf_counter):
    """{name: smallest elapsed ``clock()`` time (s)} of ``repeats`` rounds, each calling every ``fns[name]()`` once:
    taken in turns, a machine that slows down for a while slows them all, so their ratios hold better than those of
    one ``best_of`` after another.

    ``clock=time.process_time`` counts this process's CPU time only (other processes cannot inflate it).
    """
    best = dict.fromkeys(fns, float("inf"))
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = clock()
            fn()
            best[name] = min(best[name], clock() - t0)
    return best


def best_of(fn, repeats=5, clock=time.perf_counter):
    """Smallest elapsed ``clock()`` time (s) of ``repeats`` calls of ``fn()``."""
    return best_of_each({"fn": fn}, repeats, clock)["fn"]
