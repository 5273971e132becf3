"""Safety metrics of the results files (issue 22; definitions, formulas and sources in docs/metrics.md):
RSS distances (overtakezoo.envs.rss, shared with the shield) and the per-step monitor the runner drives
(monitor.py)."""

from overtakezoo.benchmark.safety.monitor import SafetyMonitor
from overtakezoo.envs.rss import RSSParams, safe_distance_opposite_direction, safe_distance_same_direction

__all__ = ["RSSParams", "SafetyMonitor", "safe_distance_opposite_direction", "safe_distance_same_direction"]
