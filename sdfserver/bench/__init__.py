"""The benchmarks behind `sdfserver bench` and docs/benchmarks.md.

Modules, in the order they build on one another (a module imports only those above it):

- ``run`` — progress lines, results that outlive a stop, the commit measured; and ``schedule`` —
  the dissertation's seeded edit schedule (§3.5), shared with the web demo. Both import nothing
  of sdfserver, so ``sdfserver.render.bench`` (the rendering benchmark, beside the renderer it
  measures) builds on them without reaching back into this package.
- ``scene`` (the seeded brushes every benchmark paints), ``timing`` (device times and their
  summary), ``reference`` (scipy's transforms, the independent check).
- ``sections`` — `sdfserver bench` itself; ``metrics`` — `sdfserver bench metrics`; ``seed`` —
  `sdfserver bench seed`, which also uses ``sdfserver.render.bench``'s runs.
- ``cli`` — which of them a command line asks for (`sdfserver bench [render|seed|metrics]`).

Nothing is imported here, so importing a leaf costs only that leaf. ``tests/core/test_bench_imports.py``
checks that the imports stay one way.
"""
