"""Training: the jitted IPPO core (`rollout`, `ppo`, `compact`), tasks and partners, and the host loop
(`trainer`: `Trainer`, `RunFiles`; `cec train`). Import the modules themselves; nothing is re-exported."""
