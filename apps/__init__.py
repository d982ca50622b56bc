"""Applications on top of the `cec` library and the `services` platform: the `cec` command, partner-zoo
building and the paper reproductions. Nothing in `cec` or `services` imports from here."""
