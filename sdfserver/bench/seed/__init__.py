"""`sdfserver bench seed`: the dissertation's chapter 4 reproduced — every table (4.1–4.6) and
figure (4.3, 4.5–4.9) with its world, chunk and focus sizes and its edit schedule
(``sdfserver.bench.schedule``), side by side with the published numbers.

Modules: ``tables`` (the dissertation's numbers and what each table and figure measures),
``measure`` (the runs, some through ``sdfserver.render.bench``; no matplotlib), ``images``
(rendered comparisons), ``figures`` (matplotlib plots, from results.json alone), ``report``
(report.md) and ``cli`` (the command).
"""
