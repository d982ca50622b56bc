"""The metrics of `cec play`: defined with every other metric in `services/metrics.py`, re-exported here under
the short names the app uses."""

from services.metrics import PLAY_ACTIVE_ROUNDS as ACTIVE_ROUNDS
from services.metrics import PLAY_AGENT_GAVE_WAY as AGENT_GAVE_WAY
from services.metrics import PLAY_PARTICIPANTS as PARTICIPANTS
from services.metrics import PLAY_ROUNDS as ROUNDS
from services.metrics import PLAY_STEP_SECONDS as STEP_SECONDS
from services.metrics import PLAY_STEPS as STEPS
from services.metrics import PLAY_SURVEYS as SURVEYS
from services.metrics import PLAY_TICK_OVERRUNS as TICK_OVERRUNS

__all__ = [
    "ACTIVE_ROUNDS",
    "AGENT_GAVE_WAY",
    "PARTICIPANTS",
    "ROUNDS",
    "STEPS",
    "STEP_SECONDS",
    "SURVEYS",
    "TICK_OVERRUNS",
]
