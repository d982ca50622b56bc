"""Evaluator: scores every new checkpoint in self-play and cross-play against the partner zoo.

Consumes the checkpoint event stream of the Redis control plane (`services.store`, consumer group:
at-least-once, results keyed by checkpoint, so a restart never re-scores finished work), plays with
`cec.evaluation` (common random numbers) on the classic and held-out level sets, and writes results to
Redis, to the run directory (`<run>/eval/update_<N>.csv`, readable by `cec report`) and to Prometheus
(docs/evaluation.md).

config.py      EvaluatorConfig, LevelSetConfig, PartnerGroupConfig (configs/evaluator.yaml)
partners.py    PartnerZoo: manifest + Redis zoo entries, loaded once, grouped into partner groups
evaluator.py   Evaluator: the service as a plain object (`score`, `handle`, `poll_once`, `serve`)
main.py        `cec evaluator` / `python -m services.evaluator`
"""
