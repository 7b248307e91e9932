"""Helpers shared by the tests: analytic geometry, test stages, spec readers, fakes."""
