"""The batch layer: studies of many episodes, run on an executor and reported.

- `tasks`: the typed `EpisodeTask` (and `TargetTask`) an executor runs, and the episode key.
- `episodes`: the worker, one task to its results row.
- `target_set`: a study's shared targets, given or sampled in difficulty bands.
- `journal`: results.jsonl (one final row per episode) and `--resume`.
- `runner`: the one study skeleton (run folder, executor, journal, progress, stop).
- `stats`, `comparisons`: per-method summaries and the paired tests against a reference.
- `compare`, `sweep`, `suite`: the studies `rodctl compare` and `rodctl sweep` run.

Nothing below this layer imports it (the import-linter contracts of pyproject.toml).
"""
