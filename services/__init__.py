"""Service adapters (gRPC, Ray, Redis) around the `cec` library; each service also runs in-process."""
