"""Generated protobuf/gRPC code for the level server's API `cec.levels.v1` (proto/cec/levels/v1/).

Do not edit: regenerate with `python scripts/gen_proto.py`. `cec.levels.wire` converts between these
messages and `Level` batches.
"""
