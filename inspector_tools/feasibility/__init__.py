"""``inspector feasibility``: qualify a part before the cell is built, from the CAD alone.

* :mod:`.study`: the command, its inputs and the simulations (on Dask, resumable);
* :mod:`.analysis`: the simulations' records turned into the study's results;
* :mod:`.surface`: the reference's surface elements and regions;
* :mod:`.stats`: the statistics on plain arrays (observability, POD, gauge study);
* :mod:`.report`: the coloured PLY, the pictures, ``feasibility.md`` and ``feasibility.html``.

A built-in plugin (entry point ``feasibility``), like ``inspector experiment``: a tool, not
the core. Importing this package is cheap.
"""
