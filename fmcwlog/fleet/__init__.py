"""Fleets: many logs at once, on every core of this machine or on a Ray cluster.

``fmcwlog process LOG_OR_FOLDER... -o OUT`` writes each log's results to ``OUT/<name>/``,
exactly what ``fmcwlog process LOG -o OUT/<name>`` writes, and records the batch in
``OUT/batch.json``; ``fmcwlog report OUT`` then writes every log's report and the fleet page.

- :mod:`~fmcwlog.fleet.inputs`: which logs a batch covers, and their folder names;
- :mod:`~fmcwlog.fleet.state`: digests for resuming, ``batch.json``, leftovers of killed workers;
- :mod:`~fmcwlog.fleet.tasks`: one log's task, its limits, its outcome;
- :mod:`~fmcwlog.fleet.worker`: the process that runs one log;
- :mod:`~fmcwlog.fleet.local` and :mod:`~fmcwlog.fleet.ray_executor`: where the workers run;
- :mod:`~fmcwlog.fleet.progress`: the progress bar's numbers;
- :mod:`~fmcwlog.fleet.batch`: a batch from the command line's paths to its outcomes.

The fleet page itself is evaluation: :mod:`fmcwlog.evaluation.fleet`.
"""
