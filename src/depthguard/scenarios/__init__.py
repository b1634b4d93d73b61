"""Scenarios that need no simulator (the MuJoCo ones live in depthguard.sim)."""
