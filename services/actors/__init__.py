"""Ray actor workers running the jitted rollout on level buffers (not built yet)."""
