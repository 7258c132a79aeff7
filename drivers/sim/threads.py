"""Choice of numba's threading layer for the simulator's commands.

numba's default layer on our machines is OpenMP (libgomp), whose idle threads spin-wait: on a
2-core machine shared with other work that costs ~40 % more CPU per frame and halves the frame
rate. The workqueue layer sleeps instead. Commands (not the library) opt in by calling
`prefer_workqueue_layer()` before their first parallel kernel.
"""

from __future__ import annotations

import os
import threading

#: Held around every numba parallel kernel launch of the simulator: the workqueue layer (used by the
#: `davio` command) is not thread-safe, and the renderer runs in the intake thread while the emulated
#: DA3 renders ground-truth views in the model worker.
PARALLEL_KERNELS = threading.Lock()


def prefer_workqueue_layer() -> str:
    """Select numba's workqueue threading layer, or the one NUMBA_THREADING_LAYER names; returns the
    layer requested. Applies it also when numba was imported before the variable was set (numba reads
    it at import). Has no effect once a parallel kernel of this process has run."""
    import numba

    layer = os.environ.get("NUMBA_THREADING_LAYER") or "workqueue"
    numba.config.THREADING_LAYER = layer
    return layer
