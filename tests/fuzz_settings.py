"""Hypothesis settings for the property-based (fuzz) tests: a small budget in the normal suite, a big
one for ``make fuzz``.

``LIDAR3D_FUZZ_EXAMPLES=N`` selects the ``lidar3d-fuzz`` profile with N examples per test (``make
fuzz`` sets 10000); unset, the ``lidar3d-suite`` profile runs each test's own small budget. Both are
derandomized (a fixed seed per test), keep no example database and have no per-example deadline, so
a run is reproducible and its time is only measured, never asserted.
"""

import os

from hypothesis import HealthCheck, settings

__all__ = ["FUZZ_EXAMPLES", "fuzz_settings"]

FUZZ_EXAMPLES = int(os.environ.get("LIDAR3D_FUZZ_EXAMPLES", "0") or 0)

settings.register_profile("lidar3d-suite", derandomize=True, database=None, deadline=None)
settings.register_profile(
    "lidar3d-fuzz",
    derandomize=True,
    database=None,
    deadline=None,
    max_examples=max(FUZZ_EXAMPLES, 1),
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


def fuzz_settings(suite_examples: int) -> settings:
    """Settings for one fuzz test: ``suite_examples`` in the normal suite, ``LIDAR3D_FUZZ_EXAMPLES`` under fuzz."""
    if FUZZ_EXAMPLES:
        return settings(settings.get_profile("lidar3d-fuzz"))
    return settings(settings.get_profile("lidar3d-suite"), max_examples=suite_examples)
