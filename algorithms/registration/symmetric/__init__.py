"""Localization of symmetric parts: features, symmetry groups, Algorithm 2, detection."""

from algorithms.registration.symmetric.algorithm2 import *  # noqa: F401,F403
