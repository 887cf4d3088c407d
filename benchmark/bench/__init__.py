"""The benches behind ``uavbench bench TARGET``: one module per target, every one in this room.

Each measures something side by side in one run and returns its numbers in a frozen result
(``lines()`` renders what the command prints; a verdict such as ``same`` or ``ok`` that the
command turns into its exit code): ``simulate`` and ``verify`` (the renderer and the dataset check),
``isa`` (the dataset's bytes under lower instruction sets), ``train`` and ``train_breakdown``
(the training loop against a plain one, by kind of work), ``ceiling`` (the convolution ceiling),
``model`` (one model's latency and size), ``ray_cluster`` (the reproduction through the process
pool and through a local Ray) and ``accelerator`` (a device's smoke reproduction and rates).
Work that needs a fresh interpreter (another instruction set, a whole reproduction as a user
starts it) runs a library function in a spawned process (:mod:`benchmark.bench.fresh_process`),
never the command line. Only ``benchmark.commands`` imports this package.
"""
