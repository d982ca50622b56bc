"""Level server: generated kitchens over gRPC (`cec.levels.v1.LevelService`), over the `cec.levels` library.

source.py      LevelSource: the logic as a plain object (sequences by seed, held-out set, validation)
curriculum.py  prioritized level replay over reported scores (off by default)
server.py      the grpc.aio adapter: servicer, token auth, health, reflection, metrics
client.py      LevelClient (unary calls, streams) and LevelStreamBuffer (background refill, reconnects)
config.py      LevelServerConfig (configs/level_server.yaml)
main.py        `cec level-server` / `python -m services.level_server`
"""
