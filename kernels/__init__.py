"""Warp kernels and functions of wcut (installed as ``wcut.kernels``).

Only ``@wp.kernel`` and ``@wp.func`` definitions live here: no Python state, no allocation,
no I/O. One module per element family or algorithm; the host code in ``wcut`` launches them.
Every kernel is valid on CPU and CUDA. Node-to-element scatters use ``atomic_add`` (a plain
add on the CPU backend, where a launch runs its threads one after another).
"""
