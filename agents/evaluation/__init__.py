"""Monte Carlo evaluation of filtered against unfiltered planners.

* :mod:`agents.evaluation.records` — episode specs, records, the CSV schema and run keys in
  one import, and the column glossary; they are defined in
  :mod:`agents.evaluation.episodes` (specs, records, columns and keys),
  :mod:`agents.evaluation.record_csv` (the results CSV) and
  :mod:`agents.evaluation.run_keys` (run keys);
* :mod:`agents.evaluation.runner` — one episode;
* :mod:`agents.evaluation.executors` — where episodes run (local process pool, Ray);
* :mod:`agents.evaluation.evaluate` — :func:`~agents.evaluation.evaluate.evaluate`, the pipeline;
* :mod:`agents.evaluation.audit` — did each risk's promise hold on the realised losses;
* :mod:`agents.evaluation.statistics` — the Wilson interval;
* :mod:`agents.evaluation.summary` — tables with Wilson intervals;
* :mod:`agents.evaluation.plots` — figures;
* :mod:`agents.evaluation.config` — :class:`~agents.evaluation.config.EvaluationConfig`, how a
  campaign runs (executor, workers, output folder, resume, figures, progress);
* :mod:`agents.evaluation.campaign` — :func:`~agents.evaluation.campaign.run_campaign`, the one
  pipeline of every evaluation command (CSV, summary and figures in one folder), and
  ``safe-nav evaluate`` (:func:`~agents.evaluation.campaign.run_evaluation`, ``--sweep``).
"""
