"""Safety metrics of the results files (issue 22; definitions, formulas and sources in docs/metrics.md):
RSS distances (rss.py) and the per-step monitor the runner drives (monitor.py)."""

from .monitor import SafetyMonitor
from .rss import RSSParams, safe_distance_opposite_direction, safe_distance_same_direction

__all__ = ["RSSParams", "SafetyMonitor", "safe_distance_opposite_direction", "safe_distance_same_direction"]
