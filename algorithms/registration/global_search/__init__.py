"""Global localization from any initial pose (see :mod:`.search`)."""

from algorithms.registration.global_search.search import *  # noqa: F401,F403
from algorithms.registration.global_search.search import GlobalLocalizationResult, global_localize, orientation_table

__all__ = ["GlobalLocalizationResult", "global_localize", "orientation_table"]
