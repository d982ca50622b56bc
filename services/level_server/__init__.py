"""Level server: gRPC streaming of generated kitchens over `cec.levels` (not built yet)."""
