"""Test configuration: deterministic hypothesis runs, so that CI results are reproducible."""

from hypothesis import settings

settings.register_profile("depthguard", derandomize=True, print_blob=True)
settings.load_profile("depthguard")
