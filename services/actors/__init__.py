"""Rollout actors: a slice of a seed's envs stepped by the jitted rollout, fed by the level server."""
