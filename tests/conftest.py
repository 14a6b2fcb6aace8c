"""Test-wide settings for the property tests (hypothesis).

- The same examples on every run, unless asked otherwise: a red run should mean the code changed, not
  that chance drew a new example. To explore new examples, run with HYPOTHESIS_PROFILE=explore (random
  draws, failures remembered in .hypothesis/).
- No time limit on an example (hypothesis' default deadline is 200 ms) and no health check on how slow
  examples are to make: on a loaded machine both fail a test that is right, and timing is what
  benchmarks measure, not tests.
"""

import os

from hypothesis import HealthCheck, settings

UNTIMED = {"deadline": None, "suppress_health_check": [HealthCheck.too_slow], "print_blob": True}
settings.register_profile("repeatable", derandomize=True, database=None, **UNTIMED)
settings.register_profile("explore", derandomize=False, **UNTIMED)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))
