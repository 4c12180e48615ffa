"""Monte Carlo evaluation of filtered against unfiltered planners.

* :mod:`agents.evaluation.records` — episode specs, records, the CSV schema and run keys;
* :mod:`agents.evaluation.runner` — one episode;
* :mod:`agents.evaluation.executors` — where episodes run (local process pool, Ray);
* :mod:`agents.evaluation.evaluate` — :func:`~agents.evaluation.evaluate.evaluate`, the pipeline;
* :mod:`agents.evaluation.audit` — did each risk's promise hold on the realised losses;
* :mod:`agents.evaluation.statistics` — the Wilson interval;
* :mod:`agents.evaluation.summary` — tables with Wilson intervals;
* :mod:`agents.evaluation.plots` — figures;
* :mod:`agents.evaluation.campaign` — ``safe-nav evaluate``: CSV, summary and figures in one folder.
"""
