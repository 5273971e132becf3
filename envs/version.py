"""The simulator's behaviour version.

Bump SIM_VERSION with every change that can alter a trajectory (dynamics, planner, NPC
behaviour, collisions, outcomes, observations deciders see), then re-measure the leaderboard
(``scripts/reproduce-leaderboard.sh``). Results record it; leaderboard rows measured with another
version are shown as stale. ``tests/envs/test_sim_version.py`` pins reference trajectories so a silent
behaviour change fails.
"""

SIM_VERSION = 2  # 2: the observation gained the speed limit and the sensor range (ego features 4, 5)
