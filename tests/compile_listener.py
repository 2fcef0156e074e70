"""Source text for a probe run in a fresh interpreter (``python -c``): it defines ``compiled``, the
list of ``module.function`` names numba compiles from then on whose module starts with
``COMPILED_PREFIX`` (a name the probe sets before this text). A kernel numba loads from its disk
cache is not compiled, so it is not listed."""

LISTENER = r'''
from numba.core import event
compiled = []

class Seen(event.Listener):
    def on_start(self, ev):
        f = ev.data["dispatcher"].py_func
        if f.__module__.startswith(COMPILED_PREFIX):
            compiled.append(f"{f.__module__}.{f.__qualname__}")

    def on_end(self, ev):
        pass

event.register("numba:compile", Seen())
'''
