"""Hardware drivers behind :mod:`calibgraph.acquire.interfaces`, installed as ``calibgraph_drivers``
(the folder is ``drivers/``; see drivers/README.md)."""
