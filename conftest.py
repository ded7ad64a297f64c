"""Settings every test of the repository shares.

Property tests (hypothesis) run derandomized: the same examples on every run and machine, so a
red run can be repeated, and nothing is stored between runs (no example database).
"""

from hypothesis import settings

settings.register_profile('repository', derandomize=True, database=None, deadline=None,
                          print_blob=True)
settings.load_profile('repository')
