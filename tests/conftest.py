"""Test-wide settings: property tests draw the same examples on every run unless asked otherwise.

A red run should mean the code changed, not that chance drew a new example. To explore new examples
locally, run with HYPOTHESIS_PROFILE=explore (random draws, failures remembered in .hypothesis/).
"""

import os

from hypothesis import settings

settings.register_profile("repeatable", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "repeatable"))
