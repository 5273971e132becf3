"""OvertakeZoo benchmark: suites, runner, metrics, results, leaderboard, archives, datasets, CLI."""
