"""The simulator's model: pure functions of the core's arrays, one file per concern, in the order
``OvertakeCore.step`` runs them (planner, controllers, dynamics, collisions, outcomes, reward, observation)."""
